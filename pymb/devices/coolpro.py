"""The CoolPro power-supply monitor ([CP] CP-MODBUS-RTU rev 1).

Telemetry (input registers 0..7) and identity (100..107) are each one
request, read through the CoolPro's map and decoded by the map's C decoder:
milliunits to volts, amps and °C, 32-bit values low word first.
"""

from __future__ import annotations

import dataclasses
import threading
from array import array
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from enum import KEEP, IntFlag
from functools import partial
from typing import Any, TypeVar

from pymb import maps
from pymb.client import Client
from pymb.devices.mapdevice import MapDevice, prepared_read
from pymb.errors import InvalidArgument
from pymb.maps import Buffers, Decoder, Map

__all__ = ["COOLPRO_BAUD_RATES", "IDENTITY_REQUEST", "CoolPro", "CoolProConfig",
           "CoolProIdentity", "CoolProStatus", "CoolProTelemetry"]


class CoolProStatus(IntFlag, boundary=KEEP):
    """Status flags, input register 7 ([CP] "Status Flags bit field").

    Bits 7..15 are reserved: they are kept as raw bits, never dropped
    (``CoolProStatus(0x8001)`` keeps 0x8000).
    """

    SYSTEM_STARTUP = 0x0001  #: device is initialising
    DAILY_RESET = 0x0002  #: daily reset has occurred (uptime counter reset)
    INPUT_MEASUREMENT_FAULT = 0x0004  #: input measurement sensor fault
    OUTPUT_MEASUREMENT_FAULT = 0x0008  #: output measurement sensor fault
    CALIBRATION_INVALID = 0x0010  #: stored calibration data failed validation
    CALIBRATION_MISSING = 0x0020  #: no calibration data stored
    TEMPERATURE_SENSOR_FAULT = 0x0040  #: temperature sensor fault

    @property
    def reserved(self) -> int:
        """The reserved bits (7..15) as they came."""
        return int(self) & 0xFF80


#: ``CoolProStatus(raw)`` by ``raw``: flag values repeat from read to read. A
#: plain dict, subscripted on the hot path (a dict subclass's subscript is a
#: method call); :func:`_status` makes a missing one (at most 1024 kept).
_STATUSES: dict[int, CoolProStatus] = {}


def _status(raw: int) -> CoolProStatus:
    if len(_STATUSES) >= 1024:
        _STATUSES.clear()
    s = _STATUSES[raw] = CoolProStatus(raw)
    return s


@dataclass(frozen=True)
class CoolProTelemetry:
    """Live telemetry, one request (input registers 0..7)."""

    input_voltage_v: float
    input_current_a: float
    output_voltage_v: float
    output_current_a: float
    temperature_c: float
    uptime_s: int
    status: CoolProStatus
    registers: array[int] = field(repr=False, compare=False)  #: raw registers 0..7


@dataclass(frozen=True)
class CoolProIdentity:
    """Device information, one request (input registers 100..107)."""

    serial_number: int
    hardware_revision: int
    firmware_version: str  #: "major.minor.patch"
    manufactured: datetime  #: UTC
    registers: array[int] = field(repr=False, compare=False)


@dataclass(frozen=True)
class CoolProConfig:
    """Configuration (holding registers 0..1). Written values are stored at
    once but take effect only after :meth:`CoolPro.reset`."""

    address: int
    baud_rate: int  #: bit/s
    baud_rate_index: int


def _coolpro_map() -> Map:
    """The CoolPro's map as the facade reads it: no silence kept after a
    reply (the device's ~8 ms answer delay is its own; the facade has always
    left the gap between reads to its caller), and an exception raised as
    the device answered it (each read is one request of declared registers:
    nothing to split)."""
    m = maps.builtin("coolpro")
    return dataclasses.replace(
        m, timing=dataclasses.replace(m.timing, turnaround=0.0),
        limits=dataclasses.replace(m.limits, split_on_exception=False))


_MAP = _coolpro_map()
T = TypeVar("T")


def coolpro_device(client: Client, address: int) -> MapDevice:
    """The :class:`~pymb.devices.MapDevice` a CoolPro is read with: its map
    as the facade reads it (no silence kept after a reply, an exception
    raised as the device answered it)."""
    return MapDevice(client, _MAP, address)
#: [CP] "Baud Rate Index": holding register 1 holds the index into this tuple
#: (the map's names of the index values).
COOLPRO_BAUD_RATES = tuple(int(v) for _, v in sorted(_MAP.points["baud_rate_index"]
                                                       .values.items()))
_ADDRESS = _MAP.points["address"].valid or (1, 247)
_IDENTITY_POINTS = [p for p in _MAP.points.values() if p.group == "identity"]
#: (function, first register, count) of the one request that reads the
#: identity ([CP] ch. 04): how identification asks "what are you?"
IDENTITY_REQUEST = (0x04, _IDENTITY_POINTS[0].address,
                    max(p.end for p in _IDENTITY_POINTS) - _IDENTITY_POINTS[0].address)
#: [CP] "Reset Command": the value written to the reset register (the only
#: one its ``valid`` range allows).
_RESET_VALUE = int((_MAP.points["reset"].valid or (0, 0))[0])
_FLOATS = ("input_voltage_v", "input_current_a", "output_voltage_v", "output_current_a",
           "temperature_c")


class _Group:
    """The slots of one group's points in its decoder's arrays."""

    def __init__(self, dec: Decoder, floats: tuple[str, ...], ints: tuple[str, ...]) -> None:
        self.decoder = dec
        self.names = (floats, ints)
        self.floats = tuple(dec.slot(n) for n in floats)
        self.ints = tuple(dec.slot(n) for n in ints)
        self.lock = threading.Lock()  # the decoder's arrays, for decode_*() without I/O


_TELEMETRY = _Group(Decoder(_MAP, [p.name for p in _MAP.points.values()
                                   if p.group == "telemetry"]),
                    _FLOATS, ("uptime_s", "status"))
_IDENTITY_NAMES = ("serial_number", "hardware_revision", "firmware_major", "firmware_minor",
                   "firmware_patch", "manufactured")
_IDENTITY = _Group(Decoder(_MAP, [p.name for p in _MAP.points.values()
                                  if p.group == "identity"]), (), _IDENTITY_NAMES)


class _Filling:
    """A :class:`CoolProTelemetry` while its fields are set, then made one
    (``__class__``, the same layout: a ``__dict__`` and a weakref slot). Its
    fields are plain attribute stores, where the frozen dataclass's
    ``__init__`` makes a call per field: a CoolPro poller's hot path."""


def _telemetry_of(dec: Decoder, own: array[int]) -> Callable[..., CoolProTelemetry]:
    """A builder of :class:`CoolProTelemetry` from ``dec``'s arrays, its slots
    looked up once: ``build(regs)`` keeps ``regs`` as its registers,
    ``build()`` a copy of ``own`` (the registers ``dec`` decoded). Called
    holding what guards the arrays."""
    b = dec.buffers
    vals, ints = b.values, b.ints
    # Each value by its slot: an array's subscript, where one struct unpack
    # of the five (and its tuple) costs more after a read's blocking wait
    # (paired medians against a simulator: 3 % of a read).
    vin, iin, vout, iout, temp = (dec.slot(n) for n in _FLOATS)
    up, st = dec.slot("uptime_s"), dec.slot("status")
    statuses, status, filling, telemetry = _STATUSES, _status, _Filling, CoolProTelemetry

    def build(regs: array[int] | None = None) -> CoolProTelemetry:
        t: Any = filling()
        t.input_voltage_v = vals[vin]
        t.input_current_a = vals[iin]
        t.output_voltage_v = vals[vout]
        t.output_current_a = vals[iout]
        t.temperature_c = vals[temp]
        t.uptime_s = ints[up]
        try:
            t.status = statuses[ints[st]]
        except KeyError:
            t.status = status(ints[st])
        t.registers = own.__copy__() if regs is None else regs
        t.__class__ = telemetry
        return t  # type: ignore[no-any-return]
    return build


_decode_telemetry = _telemetry_of(_TELEMETRY.decoder, array("H"))


def _identity(g: _Group, b: Buffers, regs: array[int], copy: bool = False) -> CoolProIdentity:
    """``b``'s values at ``g``'s slots, with ``regs`` (or, with ``copy``, a copy)."""
    if copy:
        regs = regs.__copy__()
    serial, hw, major, minor, patch, made = (b.ints[k] for k in g.ints)
    return CoolProIdentity(serial, hw, f"{major}.{minor}.{patch}",
                           datetime.fromtimestamp(made, UTC), regs)


def _identity_of(dec: Decoder, regs: array[int]) -> Callable[[], CoolProIdentity]:
    """The call that builds :class:`CoolProIdentity` from ``dec``'s arrays,
    with a copy of ``regs``."""
    return partial(_identity, _Group(dec, *_IDENTITY.names), dec.buffers, regs, True)


def _registers(regs: array[int], count: int, what: str) -> array[int]:
    if not isinstance(regs, array) or regs.typecode != "H":
        regs = array("H", regs)
    if len(regs) < count:
        raise InvalidArgument(f"{what} needs {count} registers, got {len(regs)}")
    return regs


def decode_telemetry(regs: array[int]) -> CoolProTelemetry:
    """Input registers 0..7 (an ``array('H')``) as :class:`CoolProTelemetry`,
    decoded by the CoolPro map's C decoder, with no I/O: the decoder of the
    facade, the store's reader and the logger."""
    g = _TELEMETRY
    regs = _registers(regs, g.decoder.count, "CoolPro telemetry")
    with g.lock:
        g.decoder.decode(regs)
        return _decode_telemetry(regs)


def decode_identity(regs: array[int]) -> CoolProIdentity:
    """Input registers 100..107 (an ``array('H')``) as :class:`CoolProIdentity`,
    with no I/O: the decoder of the facade and of device identification."""
    g = _IDENTITY
    regs = _registers(regs, g.decoder.count, "CoolPro identity")
    with g.lock:
        return _identity(g, g.decoder.decode(regs), regs)


class CoolPro:
    """The CoolPro at ``address`` (1..247, default 40) on ``client``: a typed
    view of the CoolPro's map (``pymb.maps.builtin("coolpro")``) read by a
    :class:`~pymb.devices.MapDevice`.

    After :meth:`set_address` and :meth:`reset`, this object talks to the
    new address. A new baud rate takes effect at the reset too: reopen the
    client at that rate (it may serve other devices on the bus, so pymb does
    not change it by itself).
    """

    #: the addresses a CoolPro can be set to ([CP]: the address register's range)
    ADDRESSES = (int(_ADDRESS[0]), int(_ADDRESS[1]))

    def __init__(self, client: Client, address: int = _MAP.device.default_address) -> None:
        if not isinstance(client, Client):
            raise InvalidArgument(f"a CoolPro needs a pymb client, got {client!r}")
        self.client = client
        self._address = self._valid_address(address)
        self._pending_address: int | None = None
        self.device = coolpro_device(client, self._address)
        #: per group read: its prepared read, which returns the group decoded
        self._groups: dict[str, Callable[[], object]] = {}
        self._telemetry: Callable[[], CoolProTelemetry] | None = None  #: its read, once made

    @property
    def address(self) -> int:
        """The device address this object talks to."""
        return self._address

    @address.setter
    def address(self, address: int) -> None:
        self._address = self._valid_address(address)
        self.device = coolpro_device(self.client, self._address)
        self._groups = {}
        self._telemetry = None

    @staticmethod
    def _valid_address(address: int) -> int:
        low, high = CoolPro.ADDRESSES
        if isinstance(address, bool) or not isinstance(address, int) or not (
            low <= address <= high
        ):
            raise InvalidArgument(f"CoolPro address must be {low}..{high}, got {address!r}")
        return address

    def _group(self, name: str, ready: Callable[[Decoder, array[int]], Callable[[], T]]
               ) -> Callable[[], T]:
        """``name``'s group made ready: a read that returns what the call
        ``ready(decoder, registers)`` made returns, called while the line's
        lock is held (the decoder's arrays are this read's)."""
        read = self._groups.get(name)
        if read is None:
            def then(fetched: tuple[tuple[Decoder, array[int]], ...]) -> Callable[[], T]:
                ((dec, regs),) = fetched
                return ready(dec, regs)
            read = self._groups[name] = prepared_read(self.device, then, group=name)
        return read  # type: ignore[return-value]

    def read_telemetry(self) -> CoolProTelemetry:
        """Voltages, currents, temperature, uptime and status flags."""
        read = self._telemetry  # a poller's hot path: no lookup by the group's name
        if read is None:
            read = self._telemetry = self._group("telemetry", _telemetry_of)
        return read()

    def read_identity(self) -> CoolProIdentity:
        """Serial number, hardware revision, firmware version, manufacture date."""
        return self._group("identity", _identity_of)()

    def read_config(self) -> CoolProConfig:
        """Device address and baud rate as stored (effective after a reset)."""
        b = self.device.read_into(group="config")[0].buffers
        address, index = b.registers[0], b.registers[1]
        baud = COOLPRO_BAUD_RATES[index] if index < len(COOLPRO_BAUD_RATES) else 0
        return CoolProConfig(address, baud, index)

    def set_address(self, address: int) -> None:
        """Store a new device address (1..247); it takes effect at :meth:`reset`."""
        new = self._valid_address(address)
        self.client.write_register(_MAP.points["address"].address, new, slave=self.address)
        self._pending_address = new

    def set_baud_rate(self, baud_rate: int) -> None:
        """Store a new baud rate (9600, 19200, 38400, 57600 or 115200 bit/s);
        it takes effect at :meth:`reset`."""
        if baud_rate not in COOLPRO_BAUD_RATES:
            raise InvalidArgument(
                f"CoolPro baud rate must be one of {list(COOLPRO_BAUD_RATES)}, got {baud_rate!r}"
            )
        self.client.write_register(_MAP.points["baud_rate_index"].address,
                                   COOLPRO_BAUD_RATES.index(baud_rate), slave=self.address)

    def reset(self) -> None:
        """Reset the device (write 0xAA55 to the reset register). The device
        echoes, then restarts: its uptime restarts and the startup flag is
        set for a moment; a stored address or baud rate takes effect now."""
        self.client.write_register(_MAP.points["reset"].address, _RESET_VALUE,
                                   slave=self.address)
        if self._pending_address is not None:
            self.address, self._pending_address = self._pending_address, None
