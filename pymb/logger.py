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

import contextlib
import os
import queue
import signal
import sys
import threading
import time
import tomllib
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

from pymb.client import Client, RtuClient, client_for_address
from pymb.devices import HUB, CoolPro, SensorHub
from pymb.devices.maps import COOLPRO
from pymb.devices.planner import request_time
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
from pymb.store import DeviceInfo, Event, OutputError, Sample, Sink, open_sink

__all__ = [
    "BusConfig",
    "DeviceConfig",
    "LogConfig",
    "Logger",
    "Summary",
    "load_config",
    "parse_device",
]

DEVICE_TYPES = ("coolpro", "hub")
_BACKOFF_FIRST, _BACKOFF_MAX = 0.5, 30.0


@dataclass
class DeviceConfig:
    """One device on a bus."""

    type: str
    address: int
    name: str = ""
    channels: int = HUB.channels
    humidity_unit: float | list[float] = 0.1

    def __post_init__(self) -> None:
        if self.type not in DEVICE_TYPES:
            raise InvalidArgument(f"unknown device type {self.type!r}; use coolpro or hub")
        low, high = (COOLPRO if self.type == "coolpro" else HUB).addresses
        if isinstance(self.address, bool) or not isinstance(self.address, int) or not (
            low <= self.address <= high
        ):
            raise InvalidArgument(
                f"{self.type} address must be {low}..{high}, got {self.address!r}")
        if not self.name:
            self.name = f"{self.type}-{self.address}"


def parse_device(spec: str) -> DeviceConfig:
    """``coolpro``, ``coolpro:42``, ``hub:250`` -> DeviceConfig."""
    kind, _, addr = spec.partition(":")
    kind = kind.strip().lower()
    if kind not in DEVICE_TYPES:
        raise InvalidArgument(f"unknown device {spec!r}; use coolpro[:ADDR] or hub[:ADDR]")
    default = COOLPRO.default_address if kind == "coolpro" else HUB.default_address
    try:
        address = int(addr) if addr else default
    except ValueError:
        raise InvalidArgument(f"bad address in {spec!r}") from None
    return DeviceConfig(kind, address)


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
        if self.interval < 0:
            raise InvalidArgument(f"bus {self.name!r}: interval must be >= 0")
        seen = set()
        for d in self.devices:
            if d.address in seen:
                raise InvalidArgument(f"bus {self.name!r}: two devices at address {d.address}")
            seen.add(d.address)

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
        """Least wire time of one poll of ``device`` at this bus's baud rate."""
        bits = 10 if self.parity.upper() == "N" else 11
        if device.type == "coolpro":
            return request_time(COOLPRO.span("telemetry")[2], self.baud, 0.008, bits)
        count = device.channels * len(HUB.blocks)
        full, rest = divmod(count, 125)
        return full * request_time(125, self.baud, 0, bits) + (
            request_time(rest, self.baud, 0, bits) if rest else 0.0)


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


def _get(table: dict[str, Any], key: str, kind: type | tuple[type, ...], where: str,
         default: Any = None) -> Any:
    value = table.get(key, default)
    if value is not None and not isinstance(value, kind):
        raise InvalidArgument(f"{where}: {key} has the wrong type ({value!r})")
    return value


def load_config(path: str | os.PathLike[str]) -> LogConfig:
    """Read a TOML configuration (see the module docstring)."""
    try:
        with open(path, "rb") as f:
            doc = tomllib.load(f)
    except OSError as e:
        raise InvalidArgument(f"cannot read {path}: {e.strerror}") from None
    except tomllib.TOMLDecodeError as e:
        raise InvalidArgument(f"{path}: {e}") from None
    out = _get(doc, "output", dict, str(path), {})
    buses = []
    for i, b in enumerate(_get(doc, "bus", list, str(path), [])):
        where = f"{path}: bus {i + 1}"
        devices = []
        for d in _get(b, "device", list, where, []):
            units = d.get("humidity_unit", 0.1)
            devices.append(DeviceConfig(
                str(_get(d, "type", str, where, "")).lower(),
                _get(d, "address", int, where, 0),
                _get(d, "name", str, where, ""),
                _get(d, "channels", int, where, HUB.channels),
                units,
            ))
        buses.append(BusConfig(
            _get(b, "name", str, where, f"bus{i + 1}"), _get(b, "port", str, where),
            _get(b, "tcp", str, where), _get(b, "baud", int, where, 9600),
            _get(b, "parity", str, where, "N"), float(_get(b, "timeout", (int, float), where, 1.0)),
            float(_get(b, "interval", (int, float), where, 0.0)), devices,
            rtu_over_tcp=_get(b, "rtu_over_tcp", str, where),
        ))
    if not buses:
        raise InvalidArgument(f"{path}: no [[bus]] configured")
    max_mb = _get(out, "max_mb", (int, float), f"{path}: output")
    max_days = _get(out, "max_age_days", (int, float), f"{path}: output")
    mqtt = _get(doc, "mqtt", dict, str(path))
    return LogConfig(
        buses, _get(out, "format", str, f"{path}: output", "sqlite"),
        _get(out, "path", str, f"{path}: output", "pymb.sqlite"),
        None if max_mb is None else int(max_mb * 1e6),
        None if max_days is None else float(max_days) * 86400,
        mqtt=None if mqtt is None else from_table(mqtt, str(path)),
    )


# -- polling ------------------------------------------------------------------------


@dataclass
class _Stats:
    samples: int = 0
    events: int = 0
    faults: int = 0
    skipped_slots: int = 0
    by_device: dict[str, int] = field(default_factory=dict)
    status: str = "starting"


_EVENT_KIND: list[tuple[type[BaseException], str]] = [
    (DeviceBusy, "busy"),
    (DeviceException, "exception"),
    (ModbusTimeout, "timeout"),
    (ProtocolError, "protocol"),
    (ModbusConnectionError, "connection"),
    (ModbusError, "error"),
]


def _kind(e: BaseException) -> str:
    return next(k for cls, k in _EVENT_KIND if isinstance(e, cls))


class _BusPoller(threading.Thread):
    """Polls one bus until told to stop; puts Samples and Events on a queue."""

    def __init__(self, bus: BusConfig, out: queue.Queue[Sample | Event], stop: threading.Event,
                 stats: _Stats, clock: Callable[[], float] = time.monotonic) -> None:
        super().__init__(name=f"pymb-bus-{bus.name}", daemon=True)
        self.bus = bus
        self.out = out
        self.stop_event = stop
        self.stats = stats
        self.clock = clock
        self.client = bus.client()
        self.readers: list[tuple[DeviceInfo, Callable[[], Any]]] = []
        for d in bus.devices:
            info = DeviceInfo(bus.name, bus.endpoint, d.type, d.address, d.name)
            if d.type == "coolpro":
                self.readers.append((info, CoolPro(self.client, d.address).read_telemetry))
            else:
                hub = SensorHub(self.client, d.address, d.channels, d.humidity_unit)
                self.readers.append((info, hub.read_all))

    def _event(self, kind: str, message: str, device: DeviceInfo | None = None,
               code: int | None = None) -> None:
        self.out.put(Event(time.time(), time.monotonic(), self.bus.name, device, kind, code,
                           message))

    def _connect(self) -> bool:
        backoff = _BACKOFF_FIRST
        while not self.stop_event.is_set():
            try:
                self.client.connect()
                return True
            except ModbusError as e:
                self.stats.status = f"{self.bus.name}: {e}"
                self._event("connection", f"{e}; retrying in {backoff:g} s")
                if self.stop_event.wait(backoff):
                    return False
                backoff = min(backoff * 2, _BACKOFF_MAX)
        return False

    def run(self) -> None:
        try:
            self._run()
        finally:
            self.client.close()

    def _run(self) -> None:
        if not self._connect():
            return
        self._event("connect", f"polling {len(self.readers)} device(s) on {self.bus.endpoint}")
        interval = self.bus.interval
        start = self.clock()
        slot = 0
        while not self.stop_event.is_set():
            if interval > 0:
                next_at = start + slot * interval
                delay = next_at - self.clock()
                if delay > 0 and self.stop_event.wait(delay):
                    break
                slot += 1
                late = int((self.clock() - start) / interval) + 1 - slot
                if late > 0:  # a long read overran whole slots: skip them
                    slot += late
                    self.stats.skipped_slots += late
            for info, read in self.readers:
                if self.stop_event.is_set():
                    break
                try:
                    data = read()
                except ModbusConnectionError as e:
                    self._fault(info, e)
                    self.client.close()
                    if not self._connect():
                        return
                    self._event("reconnect", f"reconnected to {self.bus.endpoint}")
                    break
                except ModbusError as e:
                    self._fault(info, e)
                    continue
                self.out.put(Sample(info, time.time(), time.monotonic(), data))
                self.stats.status = "ok"

    def _fault(self, info: DeviceInfo, e: ModbusError) -> None:
        self.stats.faults += 1
        code = getattr(e, "code", None) or getattr(e, "errno", None)
        self._event(_kind(e), str(e), info, code)


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

    @property
    def rate(self) -> float:
        """Samples per second over the run."""
        return self.samples / self.elapsed if self.elapsed > 0 else 0.0


class Logger:
    """Runs the pollers and writes what they produce to one sink.

    The calling thread writes (batched commits); :meth:`stop` (or SIGINT /
    SIGTERM when :meth:`run` installs handlers) ends the run cleanly: pollers
    finish their current request, the last batch is committed.
    """

    def __init__(self, config: LogConfig, *, sink: Sink | None = None,
                 status: TextIO | None = None,
                 extra_status: Callable[[], str] | None = None) -> None:
        self.config = config
        self.extra_status = extra_status  #: appended to the status line (the forwarder's)
        self.sink = sink or open_sink(config.format, config.path, max_bytes=config.max_bytes,
                                      max_age=config.max_age)
        self.status_out = status
        self._stop = threading.Event()
        self.stats = _Stats()
        self._queue: queue.Queue[Sample | Event] = queue.Queue(maxsize=10000)
        self.pollers = [_BusPoller(b, self._queue, self._stop, self.stats)
                        for b in config.buses]

    def stop(self) -> None:
        """Ask the run to end (thread- and signal-safe)."""
        self._stop.set()

    @contextlib.contextmanager
    def _signals(self) -> Iterator[None]:
        if threading.current_thread() is not threading.main_thread():
            yield
            return
        old = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
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
                    try:
                        item: Sample | Event | None = self._queue.get(timeout=0.05)
                    except queue.Empty:
                        item = None
                    if item is not None:
                        self._write(item)
                        pending += 1
                    now = time.monotonic()
                    if pending and (pending >= self.config.batch
                                    or now - last_commit >= self.config.commit_interval):
                        self.sink.commit()
                        pending, last_commit = 0, now
                    if self.status_out is not None and now - last_status >= 0.5:
                        self._print_status(now - t0)
                        last_status = now
                    if item is None and (self._stop.is_set()
                                         or not any(p.is_alive() for p in self.pollers)):
                        break
            except OutputError as e:
                failure = e
            finally:
                self._stop.set()
                for p in self.pollers:
                    p.join(10)
                try:
                    while failure is None:
                        try:
                            self._write(self._queue.get_nowait())
                        except queue.Empty:
                            break
                    self.sink.close()
                except OutputError as e:
                    failure = failure or e
        if failure is not None:
            raise failure
        elapsed = time.monotonic() - t0
        if self.status_out is not None:
            self._print_status(elapsed, final=True)
        s = self.stats
        return Summary(s.samples, s.events, s.faults, elapsed, time.process_time() - cpu0,
                       dict(s.by_device), s.skipped_slots, self.config.path)

    def _write(self, item: Sample | Event) -> None:
        if isinstance(item, Sample):
            self.sink.write(item)
            self.stats.samples += 1
            name = item.device.name
            self.stats.by_device[name] = self.stats.by_device.get(name, 0) + 1
        else:
            self.sink.event(item)
            self.stats.events += 1

    def _print_status(self, elapsed: float, final: bool = False) -> None:
        s = self.stats
        rate = s.samples / elapsed if elapsed > 0 else 0.0
        line = (f"{s.samples:,} samples  {rate:,.1f}/s  faults {s.faults}  "
                f"{elapsed:6.1f} s  {s.status}")
        if self.extra_status is not None:
            line += "  " + self.extra_status()
        out = self.status_out
        assert out is not None
        if out.isatty():
            out.write("\r\x1b[K" + line[:200] + ("\n" if final else ""))
        elif final:
            out.write(line + "\n")
        out.flush()


def single_bus_config(port: str | None, tcp: str | None, devices: Sequence[str], *,
                      baud: int = 9600, parity: str = "N", timeout: float = 1.0,
                      interval: float = 0.0, fmt: str = "sqlite", path: str = "pymb.sqlite",
                      max_mb: float | None = None, max_age_days: float | None = None,
                      name: str = "bus1", rtu_over_tcp: str | None = None) -> LogConfig:
    """A LogConfig for one bus from command-line style arguments."""
    bus = BusConfig(name, port, tcp, baud, parity, timeout, interval,
                    [parse_device(d) for d in devices], rtu_over_tcp)
    return LogConfig([bus], fmt, path, None if max_mb is None else int(max_mb * 1e6),
                     None if max_age_days is None else max_age_days * 86400)


def default_path() -> str:
    """``pymb-YYYYmmdd-HHMMSS.sqlite`` in the current directory."""
    return str(Path.cwd() / time.strftime("pymb-%Y%m%d-%H%M%S.sqlite"))


def stderr_status(quiet: bool) -> TextIO | None:
    """Where the status line goes: stderr, unless quiet."""
    return None if quiet else sys.stderr
