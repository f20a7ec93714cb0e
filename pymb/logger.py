"""The logger: several buses, several devices each, every bus in its own
thread, every sample time-stamped, every fault recorded as an event.

A bus is polled as fast as its wire allows (``interval = 0``) or every
``interval`` seconds on a drift-free schedule (slot k starts at
``start + k * interval``; a slot missed because a read ran long is skipped
and counted, not crammed in). A bus whose port fails is closed and reopened
with a doubling backoff (0.5 s to 30 s) while the other buses keep logging.

Configuration, as flags (one bus) or a TOML file (any number)::

    [output]
    format = "sqlite"          # sqlite | csv | jsonl | influx
    path = "pymb.sqlite"       # "-" for stdout (csv, jsonl)
    max_mb = 500               # optional: delete the oldest data past this size
    max_age_days = 30          # optional: ... or past this age
    on_change = false          # optional: store by exception (SQLite)
    heartbeat_s = 60           # ... every channel at least this often
    deadband = { temperature_c = 0.2, humidity_pct = 1 }   # ... engineering units

    [[bus]]
    name = "line1"
    port = "/dev/ttyUSB0"      # or tcp = "192.168.1.50:502", or
                               # rtu_over_tcp = "192.168.1.60:4001" (a raw serial server)
    baud = 9600
    parity = "N"
    timeout = 1.0
    interval = 0               # seconds between polls; 0 = as fast as the wire allows

    [[bus.device]]
    type = "coolpro"           # coolpro | hub
    address = 40
    name = "psu-a"             # optional

    [[bus.device]]
    type = "hub"
    address = 250
    channels = 100
    humidity_unit = 0.1        # or a list, one per channel
"""

from __future__ import annotations

import collections
import contextlib
import difflib
import math
import os
import queue
import signal
import socket
import sqlite3
import threading
import time
import tomllib
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

from pymb.client import Client, RtuClient, client_for_address
from pymb.devices import HUB, CoolPro, HubReading, SensorHub
from pymb.devices.hub import ALL_BLOCKS, full_sweep_spans
from pymb.devices.identify import client_asker, identify, mismatch
from pymb.devices.maps import COOLPRO, COOLPRO_GAP_S
from pymb.errors import (
    DeviceBusy,
    DeviceException,
    InvalidArgument,
    ModbusConnectionError,
    ModbusError,
    ModbusTimeout,
    ProtocolError,
)
from pymb.fleet.config import MqttConfig, from_table
from pymb.store import (
    CSV_COLUMNS,
    FORMATS,
    DeviceInfo,
    Event,
    OnChange,
    OutputError,
    Sample,
    Sink,
    open_sink,
)
from pymb.wire import bits_per_char, read_time

__all__ = [
    "FAULT_KINDS",
    "BusConfig",
    "DeviceConfig",
    "LogConfig",
    "Logger",
    "Summary",
    "check_output",
    "device_parts",
    "load_config",
    "parse_device",
]

DEVICE_TYPES = ("coolpro", "hub")
_BACKOFF_FIRST, _BACKOFF_MAX = 0.5, 30.0
_FAULTS_BEFORE_BACKOFF = 10  #: consecutive failed reads of a device before it is backed off
_STOP_WAIT = 0.1  #: seconds a stopping run waits for a poller in the middle of a request
_DRAIN_EVERY = 0.02  #: seconds the writer sleeps when the queue is empty

#: keys a device takes after its ``TYPE[:ADDRESS]`` (command line) or in TOML
DEVICE_KEYS: dict[str, tuple[str, ...]] = {
    "coolpro": ("name",),
    "hub": ("channels", "humidity_unit", "name"),
}
DEVICE_SYNTAX = "TYPE[:ADDRESS][,key=value...] (TYPE coolpro or hub)"


def _map(kind: str) -> Any:
    return COOLPRO if kind == "coolpro" else HUB


def default_address(kind: str) -> int:
    """The address a device of this type has out of the box."""
    return int(_map(kind).default_address)


@dataclass
class DeviceConfig:
    """One device on a bus. ``address`` None: the type's default address."""

    type: str
    address: int | None = None
    name: str = ""
    channels: int = HUB.channels
    humidity_unit: float | list[float] = 0.1

    def __post_init__(self) -> None:
        if self.type not in DEVICE_TYPES:
            raise InvalidArgument(f"unknown device type {self.type!r}; use coolpro or hub")
        if self.address is None:
            self.address = default_address(self.type)
        low, high = _map(self.type).addresses
        if isinstance(self.address, bool) or not isinstance(self.address, int) or not (
            low <= self.address <= high
        ):
            raise InvalidArgument(
                f"{self.type} address must be {low}..{high}, got {self.address!r}")
        if self.type == "hub":
            if isinstance(self.channels, bool) or not isinstance(self.channels, int) or not (
                    1 <= self.channels <= HUB.channels):
                raise InvalidArgument(f"hub channels must be 1..{HUB.channels}, "
                                      f"got {self.channels!r}")
            units = (self.humidity_unit if isinstance(self.humidity_unit, list)
                     else [self.humidity_unit])
            if isinstance(self.humidity_unit, list) and len(units) != self.channels:
                raise InvalidArgument(f"{len(units)} humidity units given for "
                                      f"{self.channels} channels")
            for u in units:
                if isinstance(u, bool) or not isinstance(u, (int, float)) or u not in (1, 0.1):
                    raise InvalidArgument(f"hub humidity_unit must be 1 or 0.1 (%), got {u!r}")
        if not self.name:
            self.name = f"{self.type}-{self.address}"

    @property
    def spec(self) -> str:
        """The device in the one command-line syntax, e.g. ``hub:250,channels=50``."""
        out = f"{self.type}:{self.address}"
        if self.type == "hub" and self.channels != HUB.channels:
            out += f",channels={self.channels}"
        if self.type == "hub" and not isinstance(self.humidity_unit, list) and \
                self.humidity_unit != 0.1:
            out += f",humidity_unit={self.humidity_unit:g}"
        return out


def _number(text: str, what: str, spec: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise InvalidArgument(f"{spec!r}: {what} must be a number, got {text!r}") from None


def _integer(text: str, what: str, spec: str) -> int:
    try:
        return int(text, 10)
    except ValueError:
        raise InvalidArgument(f"{spec!r}: {what} must be a whole number, got {text!r}") from None


#: words users write for a known key
_SYNONYMS = {"file": "path", "filename": "path", "out": "path", "output": "path",
             "addr": "address", "slave": "address", "unit": "address", "id": "address",
             "kind": "type", "speed": "baud", "baudrate": "baud", "baud_rate": "baud",
             "serial": "port", "device": "port", "host": "tcp", "devices": "device",
             "buses": "bus", "interval_s": "interval", "timeout_s": "timeout",
             "humidity": "humidity_unit", "channel": "channels"}


def closest(key: str, known: Sequence[str]) -> str:
    """``; did you mean 'x'?`` (or the list of known keys) for an unknown ``key``."""
    if _SYNONYMS.get(key.lower()) in known:
        return f"; did you mean {_SYNONYMS[key.lower()]!r}?"
    near = difflib.get_close_matches(key, list(known), n=1, cutoff=0.5)
    if near:
        return f"; did you mean {near[0]!r}?"
    return f"; known: {', '.join(known)}"


def parse_device(spec: str) -> DeviceConfig:
    """``TYPE[:ADDRESS][,key=value...]`` -> DeviceConfig.

    ``coolpro``, ``coolpro:42``, ``hub:250,channels=50,humidity_unit=1``;
    keys: ``name`` (both), ``channels`` and ``humidity_unit`` (hub).
    """
    kind, options = device_parts(spec)
    return DeviceConfig(kind, **options)


def device_parts(spec: str) -> tuple[str, dict[str, Any]]:
    """``TYPE[:ADDRESS][,key=value...]`` -> (type, the options given:
    ``address``, ``name``, ``channels``, ``humidity_unit``), checked for syntax."""
    head, *opts = spec.strip().split(",")
    kind, colon, addr = head.partition(":")
    kind = kind.strip().lower()
    if kind not in DEVICE_TYPES:
        raise InvalidArgument(f"unknown device {spec!r}: a device is {DEVICE_SYNTAX}")
    kwargs: dict[str, Any] = {}
    if colon:
        kwargs["address"] = _integer(addr.strip(), "the address", spec)
    for opt in opts:
        key, eq, value = opt.partition("=")
        key, value = key.strip().replace("-", "_"), value.strip()
        if key not in DEVICE_KEYS[kind] or not eq or not value:
            what = "bad option" if key in DEVICE_KEYS[kind] else f"unknown key {key!r}"
            raise InvalidArgument(
                f"{spec!r}: {what}; {kind} takes "
                f"{', '.join(k + '=...' for k in DEVICE_KEYS[kind])}"
                + (closest(key, DEVICE_KEYS[kind]) if what != "bad option" else ""))
        if key in kwargs:
            raise InvalidArgument(f"{spec!r}: {key} given twice")
        if key == "channels":
            kwargs[key] = _integer(value, key, spec)
        elif key == "humidity_unit":
            kwargs[key] = _number(value, key, spec)
        else:
            kwargs[key] = value
    return kind, kwargs


@dataclass
class BusConfig:
    """One serial line (or TCP gateway) and the devices on it."""

    name: str
    port: str | None = None
    tcp: str | None = None
    baud: int = 9600
    parity: str = "N"
    timeout: float = 1.0
    interval: float = 0.0
    devices: list[DeviceConfig] = field(default_factory=list)
    rtu_over_tcp: str | None = None

    def __post_init__(self) -> None:
        if sum(x is not None for x in (self.port, self.tcp, self.rtu_over_tcp)) != 1:
            raise InvalidArgument(
                f"bus {self.name!r}: give exactly one of port, tcp or rtu_over_tcp")
        if not self.devices:
            raise InvalidArgument(f"bus {self.name!r} has no devices")
        if not (math.isfinite(self.interval) and self.interval >= 0):
            raise InvalidArgument(f"bus {self.name!r}: interval must be a number of seconds "
                                  f">= 0, got {self.interval!r}")
        if not self.timeout > 0:
            raise InvalidArgument(f"bus {self.name!r}: timeout must be more than 0 s")
        seen: dict[int, DeviceConfig] = {}
        for d in self.devices:
            assert d.address is not None
            if d.address in seen:
                raise InvalidArgument(f"bus {self.name!r}: two devices at address {d.address} "
                                      f"({seen[d.address].name} and {d.name})")
            seen[d.address] = d

    @property
    def endpoint(self) -> str:
        """The port path or ``host:port``."""
        return self.port if self.port is not None else str(self.tcp or self.rtu_over_tcp)

    def client(self) -> Client:
        """A new (unopened) client for this bus."""
        if self.tcp is not None:
            return client_for_address(self.tcp, timeout=self.timeout,
                                      what=f"bus {self.name!r}: tcp")
        if self.rtu_over_tcp is not None:
            return client_for_address(self.rtu_over_tcp, rtu_framing=True,
                                      timeout=self.timeout,
                                      what=f"bus {self.name!r}: rtu_over_tcp")
        return RtuClient(str(self.port), self.baud, self.parity, timeout=self.timeout)

    def wire_time(self, device: DeviceConfig) -> float:
        """Least wire time of one poll of ``device`` (:mod:`pymb.wire`)."""
        bits = bits_per_char(self.parity)
        if device.type == "coolpro":
            return read_time(COOLPRO.span("telemetry")[2], self.baud, turnaround=COOLPRO_GAP_S,
                             bits=bits)
        return sum(read_time(n, self.baud, bits=bits)
                   for _, n in full_sweep_spans(device.channels))


def unresolved(host: str) -> str | None:
    """Why ``host`` does not resolve (None when it does)."""
    try:
        socket.getaddrinfo(host, None, type=socket.SOCK_STREAM)
    except socket.gaierror as e:
        return f"the host name {host!r} did not resolve ({e.strerror})"
    except (UnicodeError, OSError) as e:
        return f"the host name {host!r} did not resolve ({e})"
    return None


@dataclass
class LogConfig:
    """Everything ``pymb log`` needs."""

    buses: list[BusConfig]
    format: str = "sqlite"
    path: str = "pymb.sqlite"
    max_bytes: int | None = None
    max_age: float | None = None
    batch: int = 200  #: samples per commit, at most
    commit_interval: float = 0.5  #: seconds between commits, at most
    mqtt: MqttConfig | None = None  #: forward the samples to a broker (SQLite only)
    on_change: OnChange | None = None  #: SQLite: store by exception (``--on-change``)

    def __post_init__(self) -> None:
        check_buses(self.buses)
        if self.max_bytes is not None and not self.max_bytes > 0:
            raise InvalidArgument(f"--max-mb / max_mb must be a positive number of megabytes, "
                                  f"got {self.max_bytes / 1e6:g}")
        if self.max_age is not None and not self.max_age > 0:
            raise InvalidArgument(f"--max-age-days / max_age_days must be a positive number "
                                  f"of days, got {self.max_age / 86400:g}")


def check_buses(buses: Sequence[BusConfig]) -> None:
    """Bus names, device names and ports must each be unique; a default device
    name that two buses share is qualified with its bus's name."""
    names: dict[str, BusConfig] = {}
    ports: dict[str, BusConfig] = {}
    for b in buses:
        if b.name in names:
            raise InvalidArgument(f"two buses are named {b.name!r}")
        names[b.name] = b
        where = os.path.realpath(b.port) if b.port is not None else b.endpoint.lower()
        if where in ports:
            raise InvalidArgument(f"buses {ports[where].name!r} and {b.name!r} use the same "
                                  f"port {b.endpoint}: one port is one bus")
        ports[where] = b
    count: dict[str, int] = {}
    for b in buses:
        for d in b.devices:
            count[d.name] = count.get(d.name, 0) + 1
    for b in buses:
        for d in b.devices:
            if count[d.name] > 1:
                if d.name != f"{d.type}-{d.address}":
                    raise InvalidArgument(f"two devices are named {d.name!r}: names must be "
                                          f"unique")
                d.name = f"{b.name}-{d.name}"
    seen: set[str] = set()
    for b in buses:
        for d in b.devices:
            if d.name in seen:
                raise InvalidArgument(f"two devices are named {d.name!r}: names must be unique")
            seen.add(d.name)


_TOP_KEYS = ("output", "bus", "mqtt")
_OUTPUT_KEYS = ("format", "path", "max_mb", "max_age_days", "on_change", "heartbeat_s",
                "deadband")
_BUS_KEYS = ("name", "port", "tcp", "rtu_over_tcp", "baud", "parity", "timeout", "interval",
             "device")
_DEVICE_TOML_KEYS = ("type", "address", "name", "channels", "humidity_unit")


def _known(table: dict[str, Any], keys: Sequence[str], where: str) -> None:
    for key in table:
        if key not in keys:
            raise InvalidArgument(f"{where}: unknown key {key!r}{closest(key, keys)}")


def _get(table: dict[str, Any], key: str, kind: type | tuple[type, ...], where: str,
         default: Any = None) -> Any:
    value = table.get(key, default)
    if value is not None and (not isinstance(value, kind) or isinstance(value, bool)):
        raise InvalidArgument(f"{where}: {key} has the wrong type ({value!r})")
    return value


def _within(where: str, e: InvalidArgument) -> InvalidArgument:
    """``e`` said of ``where``, which is not repeated if ``e`` already names it."""
    text = str(e)
    return InvalidArgument(text if text.startswith(where) else f"{where}: {text}")


def load_config(path: str | os.PathLike[str]) -> LogConfig:
    """Read a TOML configuration (see the module docstring). Unknown keys and
    sections are errors that name the closest known one."""
    try:
        with open(path, "rb") as f:
            doc = tomllib.load(f)
    except IsADirectoryError:
        raise InvalidArgument(f"{path} is a directory, not a TOML file") from None
    except OSError as e:
        raise InvalidArgument(f"cannot read {path}: {e.strerror}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise InvalidArgument(f"{path}: {e}") from None
    for key in doc:
        if key not in _TOP_KEYS:
            raise InvalidArgument(f"{path}: unknown section [{key}]{closest(key, _TOP_KEYS)}")
    out = _get(doc, "output", dict, str(path), {})
    _known(out, _OUTPUT_KEYS, f"{path}: [output]")
    buses = []
    for i, b in enumerate(_get(doc, "bus", list, str(path), [])):
        where = f"{path}: bus {i + 1}"
        if not isinstance(b, dict):
            raise InvalidArgument(f"{where}: write buses as [[bus]] tables")
        _known(b, _BUS_KEYS, f"{where} [[bus]]")
        devices = []
        for j, d in enumerate(_get(b, "device", list, where, [])):
            dwhere = f"{where}, device {j + 1}"
            if not isinstance(d, dict):
                raise InvalidArgument(f"{dwhere}: write devices as [[bus.device]] tables")
            _known(d, _DEVICE_TOML_KEYS, f"{dwhere} [[bus.device]]")
            kind = _get(d, "type", str, dwhere)
            if kind is None:
                raise InvalidArgument(f"{dwhere}: give its type (coolpro or hub)")
            units = d.get("humidity_unit", 0.1)
            try:
                devices.append(DeviceConfig(
                    kind.lower(), _get(d, "address", int, dwhere),
                    _get(d, "name", str, dwhere, ""),
                    _get(d, "channels", int, dwhere, HUB.channels),
                    units,
                ))
            except InvalidArgument as e:
                raise _within(dwhere, e) from None
        try:
            buses.append(BusConfig(
                _get(b, "name", str, where, f"bus{i + 1}"), _get(b, "port", str, where),
                _get(b, "tcp", str, where), _get(b, "baud", int, where, 9600),
                _get(b, "parity", str, where, "N"),
                float(_get(b, "timeout", (int, float), where, 1.0)),
                float(_get(b, "interval", (int, float), where, 0.0)), devices,
                rtu_over_tcp=_get(b, "rtu_over_tcp", str, where),
            ))
        except InvalidArgument as e:
            raise _within(str(path), e) from None
    if not buses:
        raise InvalidArgument(f"{path}: no [[bus]] configured")
    max_mb = _get(out, "max_mb", (int, float), f"{path}: output")
    max_days = _get(out, "max_age_days", (int, float), f"{path}: output")
    for key, value in (("max_mb", max_mb), ("max_age_days", max_days)):
        if value is not None and not (math.isfinite(value) and value > 0):
            raise InvalidArgument(f"{path}: output: {key} must be a positive number, "
                                  f"got {value!r}")
    fmt = _get(out, "format", str, f"{path}: output", "sqlite")
    if fmt not in FORMATS:
        raise InvalidArgument(f"{path}: output: unknown format {fmt!r}; use one of "
                              f"{', '.join(FORMATS)}")
    mqtt = _get(doc, "mqtt", dict, str(path))
    on_change = None
    flag = out.get("on_change", False)
    if not isinstance(flag, bool):
        raise InvalidArgument(f"{path}: output: on_change must be true or false, got {flag!r}")
    if not flag and ("deadband" in out or "heartbeat_s" in out):
        raise InvalidArgument(f"{path}: output: deadband and heartbeat_s go with "
                              "on_change = true")
    if flag:
        bands = _get(out, "deadband", dict, f"{path}: output", {})
        for k in bands:
            _get(bands, k, (int, float), f"{path}: output.deadband")
        on_change = OnChange(float(_get(out, "heartbeat_s", (int, float), f"{path}: output",
                                        60.0)), {k: float(v) for k, v in bands.items()})
    try:
        return LogConfig(
            buses, fmt,
            _get(out, "path", str, f"{path}: output", "pymb.sqlite"),
            None if max_mb is None else int(max_mb * 1e6),
            None if max_days is None else float(max_days) * 86400,
            mqtt=None if mqtt is None else from_table(mqtt, str(path)),
            on_change=on_change,
        )
    except InvalidArgument as e:
        raise _within(str(path), e) from None


# -- polling ------------------------------------------------------------------------


@dataclass
class _Stats:
    samples: int = 0
    events: int = 0
    faults: int = 0
    skipped_slots: int = 0
    by_device: dict[str, int] = field(default_factory=dict)
    #: what is wrong now, by bus or device name (empty: all is well)
    problems: dict[str, str] = field(default_factory=dict)
    opened: dict[str, bool] = field(default_factory=dict)  #: bus -> port opened at least once
    last_fault: dict[str, str] = field(default_factory=dict)  #: device or bus -> last fault
    lock: threading.Lock = field(default_factory=threading.Lock)

    def fault(self, key: str, text: str) -> None:
        with self.lock:
            self.faults += 1
            self.problems[key] = text
            self.last_fault[key] = text

    def ok(self, key: str) -> None:
        if key in self.problems:
            with self.lock:
                self.problems.pop(key, None)

    def skipped(self, n: int) -> None:
        with self.lock:
            self.skipped_slots += n

    @property
    def status(self) -> str:
        """``ok``, or the latest problem (and how many more there are)."""
        with self.lock:
            problems = list(self.problems.values())
        if not problems:
            return "ok"
        more = f" (+{len(problems) - 1} more)" if len(problems) > 1 else ""
        return problems[-1] + more


_EVENT_KIND: list[tuple[type[BaseException], str]] = [
    (DeviceBusy, "busy"),
    (DeviceException, "exception"),
    (ModbusTimeout, "timeout"),
    (ProtocolError, "protocol"),
    (ModbusConnectionError, "connection"),
    (ModbusError, "error"),
]
#: the kinds of the events that mean a device gave no value (a fault): an error,
#: or a hub that answered with every block unsupported (``no_value``)
FAULT_KINDS = frozenset([*(k for _, k in _EVENT_KIND), "no_value"])


def _kind(e: BaseException) -> str:
    return next(k for cls, k in _EVENT_KIND if isinstance(e, cls))


@dataclass
class _Device:
    """A device being polled and how its polling goes."""

    info: DeviceInfo
    config: DeviceConfig
    read: Callable[[], Any]
    hub: SensorHub | None
    #: hub readings the writer has finished with, for the next sweeps to read
    #: into (no 8 KB of arrays allocated per sweep, and none freed by another
    #: thread); None: every read makes its own
    spare: collections.deque[HubReading] | None = None
    failures: int = 0  #: consecutive failed reads
    backoff: float = 0.0  #: seconds of the current backoff (0: none)
    retry_at: float = 0.0  #: not polled before this (clock)
    explained: str = ""  #: what answered, found once per run of failures


def _reading_into(hub: SensorHub, spare: collections.deque[HubReading]) -> Callable[[], Any]:
    """``hub.read_all`` into a spare reading when there is one."""
    def read() -> HubReading:
        return hub.read_all(into=spare.pop() if spare else None)
    return read


#: spare readings kept per hub: the most a writer a batch behind hands back
_SPARE_MAX = 64
#: A poller hands its samples to the writer in lists of at most this many, or
#: this old (seconds), and before it waits: one queue operation per list, not
#: two per sample. Events go at once, after the samples before them.
_BATCH_MAX = 64
_BATCH_AGE = 0.02


class _BusPoller(threading.Thread):
    """Polls one bus until told to stop; puts Samples and Events on a queue."""

    def __init__(self, bus: BusConfig, out: queue.Queue[list[Sample | Event]],
                 stop: threading.Event,
                 stats: _Stats, clock: Callable[[], float] = time.monotonic, *,
                 reuse: bool = False) -> None:
        super().__init__(name=f"pymb-bus-{bus.name}", daemon=True)
        self.bus = bus
        self.out = out
        self._batch: list[Sample | Event] = []
        self._batch_since = 0.0
        self.stop_event = stop
        self.stats = stats
        self.clock = clock
        self.client = bus.client()
        self.devices: list[_Device] = []
        stats.opened.setdefault(bus.name, False)
        for d in bus.devices:
            assert d.address is not None
            units = d.humidity_unit
            info = DeviceInfo(bus.name, bus.endpoint, d.type, d.address, d.name,
                              d.channels if d.type == "hub" else 0,
                              tuple(units) if isinstance(units, list) else units)
            if d.type == "coolpro":
                self.devices.append(_Device(info, d, CoolPro(self.client, d.address)
                                            .read_telemetry, None))
            else:
                hub = SensorHub(self.client, d.address, d.channels, d.humidity_unit)
                if reuse:
                    spare: collections.deque[HubReading] = collections.deque()
                    self.devices.append(_Device(info, d, _reading_into(hub, spare), hub, spare))
                else:
                    self.devices.append(_Device(info, d, hub.read_all, hub))

    def _event(self, kind: str, message: str, device: DeviceInfo | None = None,
               code: int | None = None) -> None:
        self._batch.append(Event(time.time(), time.monotonic(), self.bus.name, device, kind,
                                 code, message))
        self.flush()

    def flush(self) -> None:
        """Hand what was read since the last list to the writer."""
        batch, self._batch = self._batch, []
        if batch:
            self.out.put(batch)

    def take_unflushed(self) -> list[Sample | Event]:
        """What this poller read but has not handed over (for the writer, once
        the poller is left behind at stop)."""
        batch, self._batch = self._batch, []
        return batch

    def _why_not_open(self, e: ModbusError) -> str:
        host = getattr(self.client, "host", None)
        if host is not None:
            why = unresolved(host)
            if why is not None:
                return f"cannot connect to {self.bus.endpoint}: {why}"
        return str(e)

    def _connect(self) -> bool:
        backoff = _BACKOFF_FIRST
        while not self.stop_event.is_set():
            try:
                self.client.connect()
                self.stats.opened[self.bus.name] = True
                self.stats.ok(self.bus.name)
                return True
            except ModbusError as e:
                why = self._why_not_open(e)
                self.stats.fault(self.bus.name, f"bus {self.bus.name}: {why}")
                self._event("connection", f"{why}; retrying in {backoff:g} s")
                if self.stop_event.wait(backoff):
                    return False
                backoff = min(backoff * 2, _BACKOFF_MAX)
        return False

    def run(self) -> None:
        try:
            self._run()
        finally:
            self.flush()
            self.client.close()

    def _wait_for_a_device(self) -> bool:
        """With every device backed off, sleep until the first is due; False: stop."""
        due = min(d.retry_at for d in self.devices)
        delay = due - self.clock()
        return not (delay > 0 and self.stop_event.wait(min(delay, _BACKOFF_MAX)))

    def _run(self) -> None:
        if not self._connect():
            return
        self._event("connect", f"polling {len(self.devices)} device(s) on {self.bus.endpoint}")
        interval = self.bus.interval
        start = self.clock()
        slot = 0
        while not self.stop_event.is_set():
            if interval > 0:
                next_at = start + slot * interval
                delay = next_at - self.clock()
                if delay > 0:
                    self.flush()
                    if self.stop_event.wait(delay):
                        break
                slot += 1
                late = int((self.clock() - start) / interval) + 1 - slot
                if late > 0:  # a long read overran whole slots: skip them
                    slot += late
                    self.stats.skipped(late)
                    self._event("skipped", f"{late} poll slot(s) of {interval:g} s skipped: "
                                f"the polls of slot {slot - late - 1} ran "
                                f"{self.clock() - next_at:.3f} s")
            elif all(d.retry_at > self.clock() for d in self.devices):
                self.flush()
                if not self._wait_for_a_device():
                    break
                continue
            for dev in self.devices:
                if self.stop_event.is_set():
                    break
                if dev.retry_at > self.clock():
                    continue  # backed off
                if not self._poll(dev):
                    return

    def _poll(self, dev: _Device) -> bool:
        """Read one device; False when the bus is gone for good (stopping)."""
        try:
            data = dev.read()
        except ModbusConnectionError as e:
            self._fault(dev, _kind(e), str(e), getattr(e, "errno", None))
            self.client.close()
            if not self._connect():
                return False
            self._event("reconnect", f"reconnected to {self.bus.endpoint}")
            return True
        except ModbusError as e:
            code = getattr(e, "code", None) or getattr(e, "errno", None)
            self._fault(dev, _kind(e), str(e), code)
            return True
        if dev.hub is not None and data.unsupported_mask == ALL_BLOCKS:
            # Every block "unsupported": the device supplied no value at all.
            # Not a sample: a fault, and the next try probes the blocks again.
            if not dev.explained:
                dev.explained = self._explain(dev)
            dev.hub.forget_firmware()
            self._fault(dev, "no_value", f"{dev.info.name} supplied no value: {dev.explained}",
                        None, at_once=True)
            return True
        batch = self._batch
        now = time.monotonic()
        if not batch:
            self._batch_since = now
        batch.append(Sample(dev.info, time.time(), now, data))
        if len(batch) >= _BATCH_MAX or now - self._batch_since >= _BATCH_AGE:
            self.flush()
        if dev.failures:
            dev.failures, dev.backoff, dev.explained = 0, 0.0, ""
        self.stats.ok(dev.info.name)
        return True

    def _explain(self, dev: _Device) -> str:
        try:
            found = identify(client_asker(self.client), dev.info.address)
        except ModbusError as e:
            return str(e)
        return mismatch(found, dev.info.type, dev.info.address, dev.config.channels)

    def _fault(self, dev: _Device, kind: str, message: str, code: int | None, *,
               at_once: bool = False) -> None:
        dev.failures += 1
        retry = ""
        if at_once or dev.failures >= _FAULTS_BEFORE_BACKOFF:
            dev.backoff = min(max(dev.backoff * 2, _BACKOFF_FIRST), _BACKOFF_MAX)
            dev.retry_at = self.clock() + dev.backoff
            retry = f"; next try in {dev.backoff:g} s"
        self.stats.fault(dev.info.name, f"{dev.info.name}: {_short(kind, message)}")
        self._event(kind, message + retry, dev.info, code)


def _short(kind: str, message: str) -> str:
    """The status line's words for a fault."""
    if kind == "no_value":
        return message.split(": ", 1)[-1]
    if kind == "timeout":
        return "no reply (timeout)"
    return message.split(" on ", 1)[-1] if kind == "connection" else message


@dataclass
class Summary:
    """What a logging run did."""

    samples: int
    events: int
    faults: int
    elapsed: float
    cpu: float  #: process CPU seconds used
    by_device: dict[str, int]
    skipped_slots: int
    path: str
    #: bus -> why its port never opened
    never_opened: dict[str, str] = field(default_factory=dict)
    #: device -> why it never delivered a sample (its last fault)
    silent: dict[str, str] = field(default_factory=dict)

    @property
    def rate(self) -> float:
        """Samples per second over the run."""
        return self.samples / self.elapsed if self.elapsed > 0 else 0.0

    @property
    def exit_code(self) -> int:
        """0; 4 if some bus never opened its port; else 3 if some device never
        delivered a sample (``pymb log``'s exit code)."""
        return 4 if self.never_opened else 3 if self.silent else 0

    def problems(self) -> list[str]:
        """One line per bus that never opened and per device that never delivered."""
        out = [f"bus {b} never opened its port: {why}" for b, why in self.never_opened.items()]
        out += [f"{d} delivered no sample: {why}" for d, why in self.silent.items()]
        return out


class Logger:
    """Runs the pollers and writes what they produce to one sink.

    The calling thread writes (batched commits); :meth:`stop` (or SIGINT /
    SIGTERM when :meth:`run` installs handlers) ends the run at once: what
    was read is committed, and a poller still waiting for a reply is left to
    time out on its own (it is a daemon thread) rather than holding the
    stop up for its timeout.
    """

    def __init__(self, config: LogConfig, *, sink: Sink | None = None,
                 status: TextIO | None = None,
                 extra_status: Callable[[], str] | None = None) -> None:
        self.config = config
        self.extra_status = extra_status  #: appended to the status line (the forwarder's)
        if sink is None:
            check_output(config.format, config.path)
        self.status_out = status
        self._stop = threading.Event()
        self.stats = _Stats()
        # Bounded (about 10,000 samples): pollers wait when the writer lags.
        self._queue: queue.Queue[list[Sample | Event]] = queue.Queue(
            maxsize=10000 // _BATCH_MAX)
        # pymb's own sinks are done with a sample when write() returns: hub
        # sweeps may then be read into the arrays of readings already written.
        reuse = sink is None or getattr(sink, "keeps_samples", True) is False
        self.pollers = [_BusPoller(b, self._queue, self._stop, self.stats, reuse=reuse)
                        for b in config.buses]
        self._spare = {id(d.info): d.spare for p in self.pollers for d in p.devices
                       if d.spare is not None}
        self.sink = sink or open_sink(config.format, config.path, max_bytes=config.max_bytes,
                                      max_age=config.max_age, on_change=config.on_change)
        self._status_width = 0

    def stop(self) -> None:
        """Ask the run to end (thread- and signal-safe)."""
        self._stop.set()

    @contextlib.contextmanager
    def _signals(self) -> Iterator[None]:
        if threading.current_thread() is not threading.main_thread():
            yield
            return
        # SIGHUP (the terminal or ssh session closed) ends the run as SIGTERM
        # does, unless it is ignored (nohup): then it stays ignored.
        hup = [] if signal.getsignal(signal.SIGHUP) == signal.SIG_IGN else [signal.SIGHUP]
        old = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, *hup)}
        for s in old:
            signal.signal(s, lambda *_: self.stop())
        try:
            yield
        finally:
            for s, h in old.items():
                signal.signal(s, h)

    def run(self, seconds: float | None = None) -> Summary:
        """Log until stopped (or for ``seconds``); returns the summary."""
        t0, cpu0 = time.monotonic(), time.process_time()
        deadline = None if seconds is None else t0 + seconds
        last_commit = last_status = t0
        pending = 0
        failure: OutputError | None = None
        with self._signals():
            for p in self.pollers:
                p.start()
            try:
                while True:
                    if deadline is not None and time.monotonic() >= deadline:
                        self._stop.set()
                    if self._stop.is_set():
                        break
                    try:
                        item: list[Sample | Event] | None = self._queue.get_nowait()
                    except queue.Empty:
                        item = None
                        # Drain the queue in bursts: waking on every sample would cost
                        # a thread switch per sample (issue 12: CPU per sample).
                        self._stop.wait(_DRAIN_EVERY)
                    if item is not None:
                        self._write_all(item)
                        pending += len(item)
                    now = time.monotonic()
                    if pending and (pending >= self.config.batch
                                    or now - last_commit >= self.config.commit_interval):
                        self.sink.commit()
                        pending, last_commit = 0, now
                        # Leave SQLite's write lock free for a moment: another
                        # writer (the MQTT forwarder's cursor) gets its turn.
                        self._stop.wait(_DRAIN_EVERY)
                    if self.status_out is not None and now - last_status >= 0.5:
                        self._print_status(now - t0)
                        last_status = now
                    if item is None and not any(p.is_alive() for p in self.pollers):
                        break
            except OutputError as e:
                failure = e
            finally:
                self._stop.set()
                # A poller in the middle of a request finishes it (its reply is
                # logged) if that takes less than _STOP_WAIT; one waiting out a
                # long timeout is left behind.
                until = time.monotonic() + _STOP_WAIT
                for p in self.pollers:
                    p.join(max(0.0, until - time.monotonic()))
                try:
                    while failure is None:
                        try:
                            self._write_all(self._queue.get_nowait())
                        except queue.Empty:
                            break
                    # A poller left behind: what it read before the stop.
                    for p in self.pollers:
                        if failure is None and p.is_alive():
                            self._write_all(p.take_unflushed())
                    self.sink.close()
                except OutputError as e:
                    failure = failure or e
        if failure is not None:
            raise failure
        elapsed = time.monotonic() - t0
        if self.status_out is not None:
            self._print_status(elapsed, final=True)
        s = self.stats
        never = {b.name: s.last_fault.get(b.name, "").split(": ", 1)[-1] or "not yet opened"
                 for b in self.config.buses if not s.opened.get(b.name)}
        silent = {d.name: s.last_fault.get(d.name, f"{d.name}: no reply yet").split(": ", 1)[-1]
                  for b in self.config.buses if b.name not in never
                  for d in b.devices if not s.by_device.get(d.name)}
        return Summary(s.samples, s.events, s.faults, elapsed, time.process_time() - cpu0,
                       dict(s.by_device), s.skipped_slots, self.config.path, never, silent)

    def _write_all(self, items: list[Sample | Event]) -> None:
        """Write a poller's list in order: each run of samples in one call
        when the sink takes batches (SQLite: multi-row INSERTs)."""
        batch = getattr(self.sink, "write_batch", None)
        run: list[Sample] = []
        for item in items:
            if isinstance(item, Sample):
                run.append(item)
                continue
            self._samples(run, batch)
            run = []
            self.sink.event(item)
            self.stats.events += 1
        self._samples(run, batch)

    def _samples(self, samples: list[Sample], batch: Callable[[list[Sample]], None] | None,
                 ) -> None:
        if not samples:
            return
        if batch is not None:
            batch(samples)
        else:
            for sample in samples:
                self.sink.write(sample)
        by_device = self.stats.by_device
        for sample in samples:
            spare = self._spare.get(id(sample.device))
            if spare is not None and len(spare) < _SPARE_MAX and isinstance(sample.data,
                                                                             HubReading):
                spare.append(sample.data)
            name = sample.device.name
            by_device[name] = by_device.get(name, 0) + 1
        self.stats.samples += len(samples)

    def status_line(self, elapsed: float) -> str:
        """The one-line status: samples, rate, faults, skipped slots, time, state."""
        s = self.stats
        rate = s.samples / elapsed if elapsed > 0 else 0.0
        skipped = (f"  skipped {s.skipped_slots}"
                   if s.skipped_slots or any(b.interval > 0 for b in self.config.buses) else "")
        line = (f"{s.samples:,} samples  {rate:,.1f}/s  faults {s.faults}{skipped}  "
                f"{elapsed:.1f} s  {s.status}")
        if self.extra_status is not None:
            line += "  " + self.extra_status()
        return line

    def _print_status(self, elapsed: float, final: bool = False) -> None:
        line = self.status_line(elapsed)
        out = self.status_out
        assert out is not None
        try:
            if out.isatty():
                # One line that fits: a line that wrapped could not be redrawn in place.
                try:
                    width = os.get_terminal_size(out.fileno()).columns
                except (OSError, ValueError):
                    width = 80
                if len(line) > width - 1:
                    line = line[:max(0, width - 2)] + "…"
                out.write("\r\x1b[K" + line + ("\n" if final else ""))
            elif final:
                out.write(line + "\n")
            out.flush()
        except OSError:
            self.status_out = None  # the terminal went away: keep logging


def check_output(fmt: str, path: str) -> None:
    """Refuse to write ``fmt`` into an existing file of another kind: CSV or
    JSON Lines appended to a database (or to someone's document), SQLite
    tables added to a file that is not a pymb database."""
    if path == "-" or not os.path.exists(path):
        return
    if os.path.isdir(path):
        raise InvalidArgument(f"{path} is a directory; give a file name")
    if not os.path.isfile(path) or os.path.getsize(path) == 0:
        return
    try:
        with open(path, "rb") as f:
            head = f.read(512)
    except OSError as e:
        raise InvalidArgument(f"cannot read {path}: {e.strerror}") from None
    sqlite = head.startswith(b"SQLite format 3\x00")
    first = head.split(b"\n", 1)[0].rstrip(b"\r")
    if fmt == "sqlite":
        if not sqlite:
            raise InvalidArgument(f"{path} exists and is not a SQLite database: refusing to "
                                  "write into it; choose another --out")
        if not is_pymb_database(path):
            raise InvalidArgument(f"{path} is a SQLite database not written by pymb: refusing "
                                  "to add to it; choose another --out")
        return
    kind = "a SQLite database" if sqlite else "not a file pymb wrote"
    if fmt == "csv" and not sqlite and first.decode("utf-8", "replace") == ",".join(CSV_COLUMNS):
        return
    if fmt == "jsonl" and not sqlite and head.startswith(b'{"time_utc": '):
        return
    if fmt == "influx" and not sqlite and head.startswith(b"pymb_"):  # pymb's measurements
        return
    raise InvalidArgument(f"{path} exists and is {kind}, not {fmt.upper()} written by pymb: "
                          f"refusing to append {fmt.upper()} to it; choose another --out")


def is_pymb_database(path: str) -> bool:
    """True if ``path`` is a SQLite database pymb wrote (or an empty one)."""
    try:
        db = sqlite3.connect(Path(path).resolve().as_uri() + "?mode=ro", uri=True)
        try:
            tables = {r[0] for r in db.execute(
                "SELECT name FROM sqlite_master WHERE type = 'table'")}
            if not tables:
                return True
            if "meta" not in tables:
                return False
            return bool(db.execute("SELECT COUNT(*) FROM meta WHERE key = 'pymb_version'"
                                   ).fetchone()[0] == 1)
        finally:
            db.close()
    except sqlite3.Error:
        return False
