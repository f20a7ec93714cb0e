"""What ``pymb log`` logs: buses, their devices, the output; from a TOML
file (see :mod:`pymb.logger`) or built in code.

The file's ``[mqtt]`` table is the forwarder's: :func:`config_from_toml`
checks that it is a table and leaves it to the command line
(:mod:`pymb.commands.logconfig`), which joins the file, the flags and
``[mqtt]`` into one run.
"""

from __future__ import annotations

import math
import os
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pymb.client import (
    AsciiClient,
    Client,
    RtuClient,
    TlsConfig,
    UdpClient,
    client_for_address,
    parse_host_port,
)
from pymb.client.address import is_mbaps, parse_address
from pymb.devices.deviceconfig import DeviceConfig, KnownMaps, add_maps, map_device_from_toml
from pymb.devices.spec import closest
from pymb.errors import InvalidArgument
from pymb.store import FORMATS, OnChange
from pymb.store.onchange import DEADBAND_QUANTITIES
from pymb.wire import DEFAULT_BAUD, DEFAULT_PARITY, DEFAULT_TIMEOUT, bits_per_char

__all__ = ["DEFAULT_TOML_PATH", "BusConfig", "LogConfig", "check_buses", "config_from_toml",
           "load_config", "read_toml", "share_deadbands"]


@dataclass
class BusConfig:
    """One serial line (or TCP gateway, or UDP device) and the devices on it."""

    name: str
    port: str | None = None
    tcp: str | None = None
    baud: int = DEFAULT_BAUD
    parity: str = DEFAULT_PARITY
    timeout: float = DEFAULT_TIMEOUT
    interval: float = 0.0
    devices: list[DeviceConfig] = field(default_factory=list)
    rtu_over_tcp: str | None = None
    #: Modbus TCP: a poll's requests in flight on the connection at once
    pipeline: int = 1
    #: Modbus over UDP: ``HOST:PORT``
    udp: str | None = None
    #: the serial line (``port``) speaks Modbus ASCII instead of RTU
    ascii: bool = False
    #: ``tcp = "mbaps://..."``: Modbus/TCP Security's settings (None: the
    #: system's trusted CAs, no client certificate)
    tls: TlsConfig | None = None

    def __post_init__(self) -> None:
        if sum(x is not None for x in (self.port, self.tcp, self.rtu_over_tcp, self.udp)) != 1:
            raise InvalidArgument(
                f"bus {self.name!r}: give exactly one of port, tcp, rtu_over_tcp or udp")
        if self.ascii and self.port is None:
            raise InvalidArgument(f"bus {self.name!r}: ascii = true is for a serial bus (port)")
        secure = self.tcp is not None and is_mbaps(self.tcp)
        # an address is checked here, before the output is opened
        if self.tcp is not None:
            parse_address(self.tcp, what=f"bus {self.name!r}: tcp")
        for key, text in (("rtu_over_tcp", self.rtu_over_tcp), ("udp", self.udp)):
            if text is not None:
                parse_host_port(text, what=f"bus {self.name!r}: {key}")
        if self.tls is not None and not secure:
            raise InvalidArgument(f"bus {self.name!r}: tls needs tcp = \"mbaps://HOST[:PORT]\"")
        if secure and self.pipeline > 1:
            raise InvalidArgument(f"bus {self.name!r}: pipeline is for a plain tcp bus (an "
                                  "mbaps:// bus is polled one request at a time)")
        if not self.devices:
            raise InvalidArgument(f"bus {self.name!r} has no devices")
        if not (math.isfinite(self.interval) and self.interval >= 0):
            raise InvalidArgument(f"bus {self.name!r}: interval must be a number of seconds "
                                  f">= 0, got {self.interval!r}")
        if isinstance(self.pipeline, bool) or not isinstance(self.pipeline, int) or not (
                1 <= self.pipeline <= 16):
            raise InvalidArgument(f"bus {self.name!r}: pipeline must be 1..16 requests, "
                                  f"got {self.pipeline!r}")
        if self.pipeline > 1 and self.tcp is None:
            raise InvalidArgument(f"bus {self.name!r}: pipeline is for a tcp bus")
        if not self.timeout > 0:
            raise InvalidArgument(f"bus {self.name!r}: timeout must be more than 0 s")
        if self.port is not None:  # the line's baud and parity, before the output is opened
            try:
                self.client().close()
            except InvalidArgument as e:
                raise InvalidArgument(f"bus {self.name!r}: {e}") from None
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
        return self.port if self.port is not None else str(
            self.tcp or self.rtu_over_tcp or self.udp)

    def client(self) -> Client:
        """A new (unopened) client for this bus."""
        if self.tcp is not None:
            return client_for_address(self.tcp, timeout=self.timeout,
                                      what=f"bus {self.name!r}: tcp", tls=self.tls)
        if self.rtu_over_tcp is not None:
            return client_for_address(self.rtu_over_tcp, rtu_framing=True,
                                      timeout=self.timeout,
                                      what=f"bus {self.name!r}: rtu_over_tcp")
        if self.udp is not None:
            host, port = parse_host_port(self.udp, what=f"bus {self.name!r}: udp")
            return UdpClient(host, port, timeout=self.timeout)
        if self.ascii:
            return AsciiClient(str(self.port), self.baud, self.parity, timeout=self.timeout)
        return RtuClient(str(self.port), self.baud, self.parity, timeout=self.timeout)

    def wire_time(self, device: DeviceConfig) -> float:
        """Least wire time of one poll of ``device`` (:mod:`pymb.wire`): of
        its groups, each once, as its map plans them."""
        bits = bits_per_char(self.parity)
        if self.ascii:
            bits *= 2  # two characters a byte (and a few for ':', LRC, CR LF)
        return sum(device.map.plan(g, baudrate=self.baud, bits_per_char=bits).predicted_s
                   for g, _ in device.polls)


#: Commits: when the samples waiting hold COMMIT_BYTES of registers, or when
#: the oldest has waited COMMIT_INTERVAL seconds, at any rate. A power cut,
#: a SIGKILL or an OOM kill loses the samples waiting: at most the last
#: COMMIT_INTERVAL seconds (and the commit being written). Each commit writes
#: whole pages to the WAL (the last page of the samples and of their time
#: index, however few rows changed) and syncs it: a 1 Hz device commits every
#: other sample (docs/reliability.md has what that writes).
#: Forwarding to MQTT changes nothing here: the forwarder publishes from the
#: open batch (pymb.store.ids).
COMMIT_BYTES = 256 * 1024
COMMIT_INTERVAL = 1.5
#: where a TOML configuration's SQLite goes when its [output] names no path
DEFAULT_TOML_PATH = "pymb.sqlite"
#: an event (a fault, a reconnect) waits for its commit this long at most
EVENT_COMMIT_INTERVAL = 1.0


@dataclass
class LogConfig:
    """Everything ``pymb log`` needs."""

    buses: list[BusConfig]
    format: str = "sqlite"
    path: str = DEFAULT_TOML_PATH
    max_bytes: int | None = None
    max_age: float | None = None
    #: bytes of samples (their registers) a commit waits for, at most
    commit_bytes: int = COMMIT_BYTES
    #: seconds a sample waits for its commit, at most (None: COMMIT_INTERVAL)
    commit_interval: float | None = None
    on_change: OnChange | None = None  #: SQLite: store by exception (``--on-change``)
    #: DEVICE/POINT patterns (fnmatch) write commands may reach (``[writes] allow``)
    allow_writes: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        check_buses(self.buses)
        if self.max_bytes is not None and not self.max_bytes > 0:
            raise InvalidArgument(f"--max-mb / max_mb must be a positive number of megabytes, "
                                  f"got {self.max_bytes / 1e6:g}")
        if self.max_age is not None and not self.max_age > 0:
            raise InvalidArgument(f"--max-age-days / max_age_days must be a positive number "
                                  f"of days, got {self.max_age / 86400:g}")
        if self.commit_interval is not None and not (
                math.isfinite(self.commit_interval) and self.commit_interval > 0):
            raise InvalidArgument(f"--commit-interval / commit_interval_s must be a positive "
                                  f"number of seconds, got {self.commit_interval!r}")

    @property
    def commit_every(self) -> float:
        """Seconds a sample waits for its commit, at most."""
        return COMMIT_INTERVAL if self.commit_interval is None else self.commit_interval


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


def share_deadbands(buses: Sequence[BusConfig], bands: Mapping[str, float],
                    over_devices: bool) -> dict[str, float]:
    """On-change deadbands given by name for the whole run (``--deadband``,
    ``[output] deadband``), shared out: a quantity of the built-in devices is
    returned (for :class:`~pymb.store.OnChange`); a point name of the map
    devices logged goes to each of those devices that has the point, over
    the device's own ``deadband`` table when ``over_devices`` (the command
    line), under it otherwise. A name that is neither, or an amount that is
    not a number of 0 or more, is a one-line error."""
    polled = [d for b in buses for d in b.devices]
    points = sorted({p for d in polled for p in d.map.points})
    builtin: dict[str, float] = {}
    for name, band in bands.items():
        if not (math.isfinite(band) and band >= 0):
            raise InvalidArgument(f"deadband of {name} must be 0 or more, got {band!r}")
        owners = [d for d in polled if name in d.map.points]
        if name not in DEADBAND_QUANTITIES and not owners:
            known = sorted({*DEADBAND_QUANTITIES, *points})
            raise InvalidArgument(f"no quantity or point {name!r} for a deadband"
                                  f"{closest(name, known)}")
        if name in DEADBAND_QUANTITIES:
            builtin[name] = band
        for d in owners:
            if over_devices or name not in d.deadband:
                d.deadband = {**d.deadband, name: band}
    return builtin


_TOP_KEYS = ("maps", "output", "bus", "mqtt", "writes")  # [mqtt]: the forwarder's, read by the CLI
_OUTPUT_KEYS = ("format", "path", "max_mb", "max_age_days", "commit_interval_s", "on_change",
                "heartbeat_s",
                "deadband")
_BUS_KEYS = ("name", "port", "tcp", "rtu_over_tcp", "udp", "ascii", "baud", "parity", "timeout",
             "interval", "pipeline", "device", "tls")
_TLS_KEYS = ("ca", "cert", "key", "server_name", "check_hostname")


def _known(table: dict[str, Any], keys: Sequence[str], where: str) -> None:
    for key in table:
        if key not in keys:
            raise InvalidArgument(f"{where}: unknown key {key!r}{closest(key, keys)}")


def _flag(table: dict[str, Any], key: str, where: str) -> bool:
    value = table.get(key, False)
    if not isinstance(value, bool):
        raise InvalidArgument(f"{where}: {key} is true or false, got {value!r}")
    return value


#: a table's key -> its TOML header, for a table written [x] where [[x]] is meant, or the other way
_HEADERS = {"bus": "bus", "device": "bus.device", "tls": "bus.tls", "output": "output",
            "writes": "writes", "mqtt": "mqtt"}


def _get(table: dict[str, Any], key: str, kind: type | tuple[type, ...], where: str,
         default: Any = None) -> Any:
    value = table.get(key, default)
    if value is not None and (not isinstance(value, kind) or isinstance(value, bool)):
        header = _HEADERS.get(key)
        if header and kind is list and isinstance(value, dict):
            raise InvalidArgument(f"{where}: [{header}] is one table; write [[{header}]], "
                                  f"one for each {key}")
        if header and kind is dict and isinstance(value, list):
            raise InvalidArgument(f"{where}: [[{header}]] is a list of tables; write "
                                  f"[{header}], once")
        raise InvalidArgument(f"{where}: {key} has the wrong type ({value!r})")
    return value


def _within(where: str, e: InvalidArgument) -> InvalidArgument:
    """``e`` said of ``where``, which is not repeated if ``e`` already names it."""
    text = str(e)
    return InvalidArgument(text if text.startswith(where) else f"{where}: {text}")


def load_config(path: str | os.PathLike[str]) -> LogConfig:
    """Read a TOML configuration (see :mod:`pymb.logger`): its buses and
    output. Unknown keys and sections are errors that name the closest known
    one."""
    return config_from_toml(read_toml(path), path)


def read_toml(path: str | os.PathLike[str]) -> dict[str, Any]:
    """A TOML file's tables; any failure to read or parse it is an InvalidArgument."""
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except IsADirectoryError:
        raise InvalidArgument(f"{path} is a directory, not a TOML file") from None
    except OSError as e:
        raise InvalidArgument(f"cannot read {path}: {e.strerror}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise InvalidArgument(f"{path}: {e}") from None


def _allow(doc: dict[str, Any], path: str) -> tuple[str, ...]:
    """``[writes] allow = ["DEVICE/POINT", ...]``: what write commands may reach."""
    table = _get(doc, "writes", dict, path, {})
    _known(table, ("allow",), f"{path}: [writes]")
    allow = table.get("allow", [])
    if not isinstance(allow, list) or not all(isinstance(a, str) and "/" in a for a in allow):
        raise InvalidArgument(f"{path}: [writes] allow must be a list of \"DEVICE/POINT\" "
                              f"patterns, got {allow!r}")
    return tuple(allow)


def _tls(bus: dict[str, Any], where: str, base: Path) -> TlsConfig | None:
    """A bus's ``[bus.tls]`` table; its files relative to the config file."""
    table = _get(bus, "tls", dict, where)
    if table is None:
        return None
    _known(table, _TLS_KEYS, f"{where} [bus.tls]")
    files = {k: _get(table, k, str, f"{where} [bus.tls]") for k in ("ca", "cert", "key")}
    check = table.get("check_hostname", True)
    if not isinstance(check, bool):
        raise InvalidArgument(f"{where} [bus.tls]: check_hostname must be true or false")
    try:
        return TlsConfig(**{k: None if v is None else str(base / os.path.expanduser(v))
                            for k, v in files.items()},
                         server_name=_get(table, "server_name", str, f"{where} [bus.tls]"),
                         check_hostname=check)
    except InvalidArgument as e:
        raise InvalidArgument(f"{where} [bus.tls]: {str(e).removeprefix('tls ')}") from None


def config_from_toml(doc: dict[str, Any], path: str | os.PathLike[str]) -> LogConfig:
    """The buses and output of a parsed TOML configuration read from ``path``
    (named in errors). Its ``[mqtt]`` table, if any, must be a table; reading
    it is the command line's."""
    for key in doc:
        if key not in _TOP_KEYS:
            raise InvalidArgument(f"{path}: unknown section [{key}]{closest(key, _TOP_KEYS)}")
    out = _get(doc, "output", dict, str(path), {})
    _known(out, _OUTPUT_KEYS, f"{path}: [output]")
    base = Path(path).parent
    known = KnownMaps()
    add_maps(known, doc.get("maps", []), str(path), base)
    buses = []
    for i, b in enumerate(_get(doc, "bus", list, str(path), [])):
        where = f"{path}: bus {i + 1}"
        if not isinstance(b, dict):
            raise InvalidArgument(f"{where}: write buses as [[bus]] tables")
        _known(b, _BUS_KEYS, f"{where} [[bus]]")
        devices: list[DeviceConfig] = []
        for j, d in enumerate(_get(b, "device", list, where, [])):
            dwhere = f"{where}, device {j + 1}"
            if not isinstance(d, dict):
                raise InvalidArgument(f"{dwhere}: write devices as [[bus.device]] tables")
            kind = _get(d, "type", str, dwhere)
            if "map" not in d and kind is None:
                raise InvalidArgument(f"{dwhere}: give its type (coolpro, hub or a map's id) "
                                      "or map = \"FILE\"")
            if kind is not None:
                d = {**d, "type": kind.lower()}
            devices.append(map_device_from_toml(d, known, dwhere, base))
        serial = [k for k in ("baud", "parity") if k in b]
        line = next((k for k in ("tcp", "rtu_over_tcp", "udp") if k in b), None)
        if serial and "port" not in b and line is not None:  # (they would be ignored)
            raise InvalidArgument(f"{where}: {serial[0]} is for a serial line (port), not "
                                  f"{line} = \"{b[line]}\"")
        try:
            buses.append(BusConfig(
                _get(b, "name", str, where, f"bus{i + 1}"), _get(b, "port", str, where),
                _get(b, "tcp", str, where), _get(b, "baud", int, where, DEFAULT_BAUD),
                _get(b, "parity", str, where, DEFAULT_PARITY),
                float(_get(b, "timeout", (int, float), where, DEFAULT_TIMEOUT)),
                float(_get(b, "interval", (int, float), where, 0.0)), devices,
                rtu_over_tcp=_get(b, "rtu_over_tcp", str, where),
                pipeline=_get(b, "pipeline", int, where, 1),
                udp=_get(b, "udp", str, where),
                ascii=_flag(b, "ascii", where),
                tls=_tls(b, where, base),
            ))
        except InvalidArgument as e:
            raise _within(str(path), e) from None
    if not buses:
        raise InvalidArgument(f"{path}: no [[bus]] configured")
    max_mb = _get(out, "max_mb", (int, float), f"{path}: output")
    max_days = _get(out, "max_age_days", (int, float), f"{path}: output")
    commit_s = _get(out, "commit_interval_s", (int, float), f"{path}: output")
    for key, value in (("max_mb", max_mb), ("max_age_days", max_days),
                       ("commit_interval_s", commit_s)):
        if value is not None and not (math.isfinite(value) and value > 0):
            raise InvalidArgument(f"{path}: output: {key} must be a positive number, "
                                  f"got {value!r}")
    fmt = _get(out, "format", str, f"{path}: output", "sqlite")
    if fmt not in FORMATS:
        raise InvalidArgument(f"{path}: output: unknown format {fmt!r}; use one of "
                              f"{', '.join(FORMATS)}")
    _get(doc, "mqtt", dict, str(path))
    allow = _allow(doc, str(path))
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
        try:
            shared = share_deadbands(buses, {k: float(v) for k, v in bands.items()}, False)
        except InvalidArgument as e:
            raise _within(f"{path}: output", e) from None
        on_change = OnChange(float(_get(out, "heartbeat_s", (int, float), f"{path}: output",
                                        60.0)), shared)
    try:
        return LogConfig(
            buses, fmt,
            _get(out, "path", str, f"{path}: output",
                 DEFAULT_TOML_PATH if fmt == "sqlite" else "-"),
            None if max_mb is None else int(max_mb * 1e6),
            None if max_days is None else float(max_days) * 86400,
            commit_interval=None if commit_s is None else float(commit_s),
            on_change=on_change, allow_writes=allow,
        )
    except InvalidArgument as e:
        raise _within(str(path), e) from None
