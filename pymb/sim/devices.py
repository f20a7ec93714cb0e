"""Device models: a CoolPro and a sensor hub, as pure functions of requests.

A device takes a request PDU (function code first) and returns the reply PDU,
or ``None`` for silence; it does no I/O and knows nothing of framing or
timing, which the bus adds (:mod:`pymb.sim.bus`). Every address, block,
range, write limit, firmware profile, reset value, baud table and status bit
comes from :mod:`pymb.devices.maps`; no register number appears here.

State lives in ``array('H')`` register images, so a read is one slice, one
``byteswap`` and one ``tobytes``. Values are a deterministic function of the
device's seed and the simulated time of its :class:`~pymb.sim.clock.SimClock`:
freeze or step the clock and the values follow. Test hooks (pin a raw
value, force a channel offline, raise a status bit, change the firmware) take
effect at once.
"""

from __future__ import annotations

import bisect
import calendar
import functools
import math
import random
import sys
import threading
from array import array
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, fields
from enum import IntEnum
from typing import Any, ClassVar, TypeVar

from pymb._native import FunctionCode
from pymb.devices.maps import (
    COOLPRO,
    COOLPRO_BAUD_RATES,
    COOLPRO_GAP_S,
    COOLPRO_RESET_VALUE,
    COOLPRO_STATUS_BITS,
    HUB,
    HUB_FIRMWARE_PROFILES,
    Access,
    Block,
    Register,
    Type,
)
from pymb.errors import (
    DeviceFailure,
    IllegalDataAddress,
    IllegalDataValue,
    IllegalFunction,
    InvalidArgument,
)
from pymb.sim.clock import SimClock

__all__ = [
    "Channel",
    "CoolProDevice",
    "Device",
    "ExceptionCode",
    "Function",
    "HubDevice",
    "exception_pdu",
    "parse_firmware",
    "sign_magnitude",
]

_SWAP = sys.byteorder == "little"  # registers go on the wire big-endian
_MAX_READ = COOLPRO.max_read  # [MB-AP] 6.3, 6.4: 1..125 registers per read
_M64 = 0xFFFF_FFFF_FFFF_FFFF
_TWO_PI = 2.0 * math.pi


#: Modbus function codes ([MB-AP] 6): the compiler's, from libmodbus's modbus.h.
Function = FunctionCode


class ExceptionCode(IntEnum):
    """Exception codes both documents list ([CP] ch. 05, [HUB] 2.3.2.3): the
    codes of :mod:`pymb.errors`' classes."""

    ILLEGAL_FUNCTION = IllegalFunction.default_code
    ILLEGAL_DATA_ADDRESS = IllegalDataAddress.default_code
    ILLEGAL_DATA_VALUE = IllegalDataValue.default_code
    #: the CoolPro's "Slave Device Failure", the hub's "busy"
    DEVICE_FAILURE = DeviceFailure.default_code


def exception_pdu(function: int, code: int) -> bytes:
    """The exception reply to ``function``: function | 0x80, then ``code``."""
    return bytes(((function | 0x80) & 0xFF, code & 0xFF))


def _mix(x: int) -> int:
    """splitmix64's finaliser: a fast, well-spread 64-bit hash step."""
    x = (x + 0x9E3779B97F4A7C15) & _M64
    x = ((x ^ (x >> 30)) * 0xBF58476D1CE4E5B9) & _M64
    x = ((x ^ (x >> 27)) * 0x94D049BB133111EB) & _M64
    return x ^ (x >> 31)


def _noise(*keys: int) -> float:
    """A number in [0, 1) that depends only on ``keys`` (seed, channel, tick, salt)."""
    h = 0
    for k in keys:
        h = _mix(h ^ (k & _M64))
    return h / 18446744073709551616.0


def sign_magnitude(tenths: int) -> int:
    """Encode tenths of a degree as [HUB] 3 does: bit 15 sign, bits 14..0
    magnitude. The magnitude is capped so the result is never 0xFFFF."""
    if tenths < 0:
        return 0x8000 | min(-tenths, 0x7FFE)
    return min(tenths, 0x7FFE)


def parse_firmware(version: str | Sequence[int]) -> tuple[int, ...]:
    """``"2.19"``, ``"V2.19"`` or ``(2, 19)`` as a tuple of ints, for comparing."""
    if isinstance(version, str):
        text = version.strip().lstrip("vV")
        try:
            parts = tuple(int(p) for p in text.split("."))
        except ValueError:
            parts = ()
        if not parts:
            raise InvalidArgument(f"firmware version must look like 2.19, got {version!r}")
        return parts
    return tuple(int(p) for p in version)


_F = TypeVar("_F", bound=Callable[..., Any])


def _locked(method: _F) -> _F:
    """Run ``method`` holding the device's lock (the bus thread and a test
    thread may both touch a device)."""

    @functools.wraps(method)
    def wrapper(self: Device, *args: Any, **kwargs: Any) -> Any:
        with self.lock:
            return method(self, *args, **kwargs)

    return wrapper  # type: ignore[return-value]


def _swapped(regs: array[int]) -> bytes:
    if _SWAP:
        regs.byteswap()
    return regs.tobytes()


class Device:
    """What the bus needs of a simulated device.

    ``address`` and ``baud`` are the ones it answers at *now* (a CoolPro
    changes them only at a reset). ``handle`` returns the reply PDU or None.
    """

    kind: ClassVar[str] = ""
    #: exception code the ``busy`` fault answers with
    busy_code: ClassVar[int] = ExceptionCode.DEVICE_FAILURE

    def __init__(self, address: int, *, baud: int, seed: int, clock: SimClock | None) -> None:
        self.seed = int(seed)
        self.clock = clock if clock is not None else SimClock()
        self._address = address
        self._baud = baud
        self.rng = random.Random(_mix(self.seed ^ 0x5EED))  # turnaround jitter, faults
        #: held by the bus around :meth:`handle` and by every public setter
        self.lock = threading.RLock()

    @property
    def address(self) -> int:
        """The slave address the device answers at."""
        return self._address

    @property
    def baud(self) -> int:
        """The line speed the device listens at (8N1)."""
        return self._baud

    def turnaround(self) -> float:
        """Seconds from the end of a request to the start of the reply."""
        return 0.0

    def handle(self, pdu: bytes) -> bytes | None:
        """The reply PDU to request ``pdu`` addressed to this device."""
        raise NotImplementedError

    def handle_broadcast(self, pdu: bytes) -> None:
        """A request sent to address 0: never answered."""

    def idle(self) -> None:
        """The line is quiet: a chance to bring values up to date off the
        request path."""

    def sensor_fault(self, rng: random.Random, seconds: float, *, bits: int | None = None,
                     channels: Sequence[int] | None = None) -> str:
        """Raise a sensor fault for ``seconds``; returns what it did."""
        raise NotImplementedError

    def describe(self) -> str:
        """One line for the command line's banner."""
        return f"{self.kind} at address {self.address} ({self.baud} 8N1)"

    def __repr__(self) -> str:
        return f"<{type(self).__name__} address={self.address} baud={self.baud}>"


# ---------------------------------------------------------------------------
# CoolPro


def _spaces(function: int) -> list[tuple[int, int]]:
    """(first, count) of each run of contiguous COOLPRO registers read by ``function``."""
    runs: list[list[int]] = []
    for r in sorted((r for r in COOLPRO.registers if r.function == function),
                    key=lambda r: r.address):
        if runs and runs[-1][0] + runs[-1][1] == r.address:
            runs[-1][1] += r.count
        else:
            runs.append([r.address, r.count])
    return [(a, n) for a, n in runs]


def _status_bit(name: str) -> int:
    for bit, (n, _) in COOLPRO_STATUS_BITS.items():
        if n == name:
            return 1 << bit
    raise KeyError(name)


_STARTUP = _status_bit("SYSTEM_STARTUP")
_DAILY = _status_bit("DAILY_RESET")
#: status bit -> telemetry points that read 0 while it is raised (the sensor
#: behind them cannot be read).
_FAULT_ZEROES: dict[int, tuple[str, ...]] = {
    _status_bit("INPUT_MEASUREMENT_FAULT"): ("input_voltage_v", "input_current_a"),
    _status_bit("OUTPUT_MEASUREMENT_FAULT"): ("output_voltage_v", "output_current_a"),
    _status_bit("TEMPERATURE_SENSOR_FAULT"): ("temperature_c",),
}
#: bits the value model raises now and then, with their weights
_EPISODE_BITS = (
    (_status_bit("INPUT_MEASUREMENT_FAULT"), 3),
    (_status_bit("OUTPUT_MEASUREMENT_FAULT"), 3),
    (_status_bit("TEMPERATURE_SENSOR_FAULT"), 3),
    (_status_bit("CALIBRATION_INVALID"), 1),
)
_SENSOR_FAULT_BITS = tuple(_FAULT_ZEROES)
_DEFAULT_MANUFACTURED = calendar.timegm((2026, 6, 1, 0, 0, 0, 0, 0, 0))


class CoolProDevice(Device):
    """The CoolPro power-supply monitor of [CP] and [NOTES].

    Holding registers (FC 0x03 read, 0x06 write): device address, baud index,
    reset. A write is echoed and stored; the stored address and baud take
    effect at the next reset (writing ``COOLPRO_RESET_VALUE`` to the reset
    register, echoed first). Input registers (FC 0x04): telemetry in
    milliunits and the identity block.

    Options: ``gap`` (seconds from a request's end to the reply, [CP] "about
    8 ms"; 0 for benchmarks), ``serial_number`` (default 12345, the
    document's example, plus the distance of ``address`` from 40),
    ``hardware_revision``, ``firmware`` (major, minor, patch),
    ``manufactured`` (Unix time), ``uptime`` (seconds already up at start),
    ``startup_seconds`` (how long SYSTEM_STARTUP stays raised after a reset),
    ``dynamic`` (False: no status-fault episodes from the value model).

    Errors, in the standard's order ([MB-AP] 6): a function other than 0x03,
    0x04, 0x06 answers 01; a quantity outside 1..125 answers 03; a range not
    inside one block answers 02; a write value outside the register's range
    answers 03.
    """

    kind = "coolpro"
    LOAD_STEP_S: ClassVar[float] = 20.0  #: how often the load may change
    EPISODE_WINDOW_S: ClassVar[float] = 600.0  #: one status-fault episode chance per window
    EPISODE_PROBABILITY: ClassVar[float] = 0.25
    DAILY_RESET_S: ClassVar[int] = 86400  #: uptime wraps and DAILY_RESET is raised

    def __init__(
        self,
        address: int = COOLPRO.default_address,
        *,
        baud: int = COOLPRO.default_baud,
        seed: int = 0,
        clock: SimClock | None = None,
        gap: float = COOLPRO_GAP_S,
        serial_number: int | None = None,
        hardware_revision: int = 1,
        firmware: tuple[int, int, int] | str = (1, 0, 0),
        manufactured: int = _DEFAULT_MANUFACTURED,
        uptime: float = 0.0,
        startup_seconds: float = 2.0,
        dynamic: bool = True,
    ) -> None:
        lo, hi = COOLPRO["address"].valid or (1, 247)
        if not lo <= address <= hi:
            raise InvalidArgument(f"coolpro address must be {lo}..{hi}, got {address}")
        if baud not in COOLPRO_BAUD_RATES:
            raise InvalidArgument(
                f"coolpro baud must be one of {', '.join(map(str, COOLPRO_BAUD_RATES))}, "
                f"got {baud}")
        if gap < 0:
            raise InvalidArgument(f"gap must be 0 or more seconds, got {gap!r}")
        super().__init__(address, baud=baud, seed=seed, clock=clock)
        self.gap = float(gap)
        self.startup_seconds = float(startup_seconds)
        self.dynamic = dynamic
        self.resets = 0  #: resets done (commands and :meth:`reset`)
        # One image per run of contiguous registers, per read function.
        self._spaces: dict[int, list[tuple[int, int, array[int]]]] = {
            fc: [(a, n, array("H", bytes(2 * n))) for a, n in _spaces(fc)]
            for fc in (Function.READ_HOLDING_REGISTERS, Function.READ_INPUT_REGISTERS)
        }
        self._where: dict[str, tuple[array[int], int]] = {}
        for r in COOLPRO.registers:
            for first, n, img in self._spaces[r.function]:
                if first <= r.address < first + n:
                    self._where[r.name] = (img, r.address - first)
        self._telemetry_image = self._where["input_voltage_v"][0]
        self._holding = {r.address: r for r in COOLPRO.registers
                         if r.function == Function.READ_HOLDING_REGISTERS}
        self._pins: dict[str, int] = {}
        self._forced: dict[int, float] = {}  # status mask -> simulated expiry
        self._put("address", address)
        self._put("baud_rate_index", COOLPRO_BAUD_RATES.index(baud))
        if serial_number is None:
            serial_number = (12345 + address - COOLPRO.default_address) & 0xFFFFFFFF
        fw = parse_firmware(firmware) if isinstance(firmware, str) else tuple(firmware)
        if len(fw) != 3:
            raise InvalidArgument(f"coolpro firmware is major.minor.patch, got {firmware!r}")
        self._put("serial_number", serial_number)
        self._put("hardware_revision", hardware_revision)
        self._put("firmware_major", fw[0])
        self._put("firmware_minor", fw[1])
        self._put("firmware_patch", fw[2])
        self._put("manufactured", manufactured)
        self._boot = self.clock.now() - float(uptime)

    # -- registers -----------------------------------------------------------------

    def _put(self, name: str, value: int) -> None:
        img, i = self._where[name]
        if COOLPRO[name].type is Type.U32_LE_WORDS:
            img[i] = value & 0xFFFF
            img[i + 1] = (value >> 16) & 0xFFFF
        else:
            img[i] = value & 0xFFFF

    @_locked
    def register(self, name: str) -> int:
        """The raw value of a point of :data:`~pymb.devices.maps.COOLPRO` by
        name, as a read now would return it (32-bit points combined)."""
        img, i = self._where[name]
        if img is self._telemetry_image:
            self._update_telemetry()
        if COOLPRO[name].type is Type.U32_LE_WORDS:
            return img[i] | (img[i + 1] << 16)
        return img[i]

    @property
    def pending_address(self) -> int:
        """The address stored by the last write, in effect after a reset."""
        return self.register("address")

    @property
    def pending_baud(self) -> int:
        """The baud rate stored by the last write, in effect after a reset."""
        return COOLPRO_BAUD_RATES[self.register("baud_rate_index")]

    @property
    def uptime(self) -> float:
        """Seconds since the last reset (simulated)."""
        return self.clock.now() - self._boot

    def turnaround(self) -> float:
        """The document's fixed inter-frame gap (``gap``)."""
        return self.gap

    # -- test hooks ---------------------------------------------------------------

    @_locked
    def pin(self, name: str, raw: int) -> None:
        """Make telemetry point ``name`` read ``raw`` until :meth:`unpin`."""
        reg = COOLPRO[name]
        if reg.function != Function.READ_INPUT_REGISTERS or self._where[name][0] is not \
                self._telemetry_image:
            raise InvalidArgument(f"{name} is not a telemetry point; pin one of "
                                  f"{', '.join(r.name for r in COOLPRO.group('telemetry'))}")
        self._pins[name] = int(raw)

    @_locked
    def unpin(self, name: str | None = None) -> None:
        """Let ``name`` (or every pinned point) follow the value model again."""
        if name is None:
            self._pins.clear()
        else:
            self._pins.pop(name, None)

    @_locked
    def set_identity(self, **values: int) -> None:
        """Set identity points by name (``serial_number=...``, ``firmware_major=...``)."""
        for name, value in values.items():
            if COOLPRO[name].group != "identity":
                raise InvalidArgument(f"{name} is not an identity point")
            self._put(name, value)

    @_locked
    def set_status(self, mask: int, seconds: float | None = None) -> None:
        """Raise the status bits in ``mask`` (reserved bits 7..15 too), for
        ``seconds`` of simulated time or until :meth:`clear_status`."""
        if not 0 < mask <= 0xFFFF:
            raise InvalidArgument(f"status mask must be 1..0xFFFF, got {mask!r}")
        until = math.inf if seconds is None else self.clock.now() + seconds
        for bit in range(16):
            if mask & (1 << bit):
                self._forced[1 << bit] = until

    @_locked
    def clear_status(self, mask: int = 0xFFFF) -> None:
        """Drop bits raised by :meth:`set_status` (the model's own stay)."""
        for m in list(self._forced):
            if m & mask:
                del self._forced[m]

    @_locked
    def reset(self) -> None:
        """Reset the device: the stored address and baud take effect, uptime
        restarts at 0 and SYSTEM_STARTUP is raised for ``startup_seconds``."""
        self._address = self.register("address")
        self._baud = COOLPRO_BAUD_RATES[self.register("baud_rate_index")]
        self._boot = self.clock.now()
        self.resets += 1

    @_locked
    def sensor_fault(self, rng: random.Random, seconds: float, *, bits: int | None = None,
                     channels: Sequence[int] | None = None) -> str:
        """Raise one measurement-fault bit (or ``bits``) for ``seconds``."""
        mask = bits if bits else rng.choice(_SENSOR_FAULT_BITS)
        self.set_status(mask, seconds)
        return f"status 0x{mask:04X} for {seconds:g} s"

    # -- the value model -------------------------------------------------------------

    @_locked
    def status(self, t: float | None = None) -> int:
        """The status flags at simulated time ``t`` (default now)."""
        if t is None:
            t = self.clock.now()
        up = t - self._boot
        bits = 0
        if up < self.startup_seconds:
            bits |= _STARTUP
        if up >= self.DAILY_RESET_S:
            bits |= _DAILY
        if self.dynamic:
            bits |= self._episode(t)
        if self._forced:
            for m, until in list(self._forced.items()):
                if until > t:
                    bits |= m
                else:
                    del self._forced[m]
        return bits

    def _episode(self, t: float) -> int:
        """The status bit of a fault episode the model runs at ``t``, or 0."""
        w = int(t // self.EPISODE_WINDOW_S)
        if _noise(self.seed, 11, w) >= self.EPISODE_PROBABILITY:
            return 0
        length = 5.0 + 40.0 * _noise(self.seed, 12, w)
        start = w * self.EPISODE_WINDOW_S + (self.EPISODE_WINDOW_S - length) * _noise(
            self.seed, 13, w)
        if not start <= t < start + length:
            return 0
        pick = _noise(self.seed, 14, w) * sum(wt for _, wt in _EPISODE_BITS)
        for bit, wt in _EPISODE_BITS:
            if pick < wt:
                return bit
            pick -= wt
        return _EPISODE_BITS[-1][0]

    def _load_ma(self, step: int) -> float:
        levels = (1500.0, 2400.0, 3200.0, 3200.0, 4100.0, 5600.0)
        return levels[int(_noise(self.seed, 1, step) * len(levels))]

    def _update_telemetry(self) -> None:
        t = self.clock.now()
        tq = math.floor(t * 10.0) / 10.0  # the device measures at 10 Hz
        tick = int(tq * 10.0)
        s = self.seed
        # Load steps every LOAD_STEP_S, settling over half a second.
        step = int(tq // self.LOAD_STEP_S)
        new, old = self._load_ma(step), self._load_ma(step - 1)
        settle = min(1.0, (tq - step * self.LOAD_STEP_S) / 0.5)
        iout = old + (new - old) * settle + 20.0 * math.sin(_TWO_PI * tq / 7.3) + 16.0 * (
            _noise(s, 2, tick) - 0.5)
        vout = 24000.0 - 0.01 * (iout - 3200.0) + 4.0 * math.sin(_TWO_PI * tq * 1.7)
        vin = 24500.0 - 0.05 * (iout - 3200.0) + 55.0 * math.sin(_TWO_PI * tq * 1.37) + 20.0 * (
            _noise(s, 3, tick) - 0.5)
        iin = iout * vout / (vin * 0.964)
        temp = 25800.0 + 0.9 * (new - 3200.0) * settle + 0.9 * (old - 3200.0) * (1 - settle) \
            + 1500.0 * math.sin(_TWO_PI * t / 3600.0 + _TWO_PI * _noise(s, 4)) \
            + 30.0 * (_noise(s, 5, tick) - 0.5)
        up = max(0.0, t - self._boot)
        status = self.status(t)
        put = self._put
        put("input_voltage_v", max(0, min(0xFFFF, round(vin))))
        put("input_current_a", max(0, min(0xFFFF, round(iin))))
        put("output_voltage_v", max(0, min(0xFFFF, round(vout))))
        put("output_current_a", max(0, min(0xFFFF, round(iout))))
        put("temperature_c", max(0, min(0xFFFF, round(temp))))
        put("uptime_s", int(up) % self.DAILY_RESET_S)
        put("status", status)
        for bit, names in _FAULT_ZEROES.items():
            if status & bit:
                for name in names:
                    put(name, 0)
        for name, raw in self._pins.items():
            put(name, raw)

    # -- requests ---------------------------------------------------------------------

    def handle(self, pdu: bytes) -> bytes | None:
        """Answer one request PDU as [CP] and [NOTES] say."""
        fc = pdu[0]
        if fc not in COOLPRO.function_codes:
            return exception_pdu(fc, ExceptionCode.ILLEGAL_FUNCTION)
        if len(pdu) != 5:
            return exception_pdu(fc, ExceptionCode.ILLEGAL_DATA_VALUE)
        first = (pdu[1] << 8) | pdu[2]
        value = (pdu[3] << 8) | pdu[4]
        if fc == Function.WRITE_SINGLE_REGISTER:
            return self._write(pdu, first, value)
        if not 1 <= value <= _MAX_READ:
            return exception_pdu(fc, ExceptionCode.ILLEGAL_DATA_VALUE)
        for start, n, img in self._spaces[fc]:
            if start <= first and first + value <= start + n:
                if img is self._telemetry_image:
                    self._update_telemetry()
                i = first - start
                return bytes((fc, 2 * value)) + _swapped(img[i:i + value])
        return exception_pdu(fc, ExceptionCode.ILLEGAL_DATA_ADDRESS)

    def _write(self, pdu: bytes, address: int, value: int) -> bytes:
        fc = pdu[0]
        reg: Register | None = self._holding.get(address)
        if reg is None or reg.access is Access.R:
            return exception_pdu(fc, ExceptionCode.ILLEGAL_DATA_ADDRESS)
        if reg.valid is not None and not reg.valid[0] <= value <= reg.valid[1]:
            return exception_pdu(fc, ExceptionCode.ILLEGAL_DATA_VALUE)
        if reg.valid == (COOLPRO_RESET_VALUE, COOLPRO_RESET_VALUE):
            self.reset()  # the bus still answers from the old address: the echo goes first
        else:
            self._put(reg.name, value)
        return bytes(pdu)

    def handle_broadcast(self, pdu: bytes) -> None:
        """Standard Modbus ([MB-SL] 2.1): a broadcast write is carried out
        without a reply; broadcast reads are ignored."""
        if pdu[0] == Function.WRITE_SINGLE_REGISTER:
            self.handle(pdu)

    def describe(self) -> str:
        fw = ".".join(str(self.register(n)) for n in
                      ("firmware_major", "firmware_minor", "firmware_patch"))
        return (f"coolpro at address {self.address} ({self.baud} 8N1), serial "
                f"{self.register('serial_number')}, firmware {fw}, "
                f"gap {self.gap * 1000:g} ms")


# ---------------------------------------------------------------------------
# Sensor hub


@dataclass
class Channel:
    """What is plugged into one hub channel; see :meth:`HubDevice.configure`.

    ``present``: a sensor is paired (else the whole channel reads offline).
    ``temperature``/``humidity``: the main probe's kinds; ``pressure``: a
    pressure sensor (pressure temperature and pressure blocks);
    ``temperature2``: a second probe. Voltage and RSSI come with any present
    sensor. ``humidity_tenths``: the humidity unit is 0.1 % (else 1 %).
    """

    present: bool = True
    temperature: bool = True
    humidity: bool = True
    pressure: bool = False
    temperature2: bool = False
    humidity_tenths: bool = True


#: which Channel flag each HUB block depends on (block names from maps.HUB)
_BLOCK_SENSOR = {
    "temperature_c": "temperature",
    "humidity_pct": "humidity",
    "pressure_temperature_c": "pressure",
    "pressure_kpa": "pressure",
    "voltage_mv": "present",
    "rssi_dbm": "present",
    "temperature2_c": "temperature2",
}
_BLOCK_SENSORS = tuple((b.name, _BLOCK_SENSOR[b.name]) for b in HUB.blocks)
_OFFLINE = HUB.blocks[0].markers[0][0]  # 0xFFFF on every block
_ALL_OFFLINE = [_OFFLINE] * len(HUB.blocks)
_NO_HUMIDITY = {False: HUB.block("humidity_pct").markers[1][0],  # 1 % unit
                True: HUB.block("humidity_pct").markers[2][0]}  # 0.1 % unit
_HUB_ADDRESSES = HUB.addresses  # [HUB] 2.3.1, [NOTES]


def _profiles() -> list[tuple[tuple[int, ...], int, frozenset[str]]]:
    return sorted((parse_firmware(v), ch, frozenset(blocks))
                  for v, (ch, blocks) in HUB_FIRMWARE_PROFILES.items())


@dataclass
class _Model:
    """Per-channel parameters of the value model, drawn once from the seed."""

    key: int  # hash of (seed, channel): the root of its noise
    phase: float
    temp: float  # tenths of a degree
    temp_amp: float
    temp_period: float
    humidity: float  # 0.1 %
    p_temp: float
    pressure: float  # kPa
    volt: float  # mV
    rssi: float  # dBm
    temp2: float


class HubDevice(Device):
    """The 100-channel sensor hub of [HUB] and [NOTES].

    FC 0x03 only (0x10 answers 0x90/01, any other function 01); registers
    from ``HUB.first`` for ``HUB.count``; a read of 1..125 registers that
    touches only registers the firmware has, else 02; addresses 1..255;
    broadcasts are never answered.

    Options: ``firmware`` (a version; the profile is the first of
    HUB_FIRMWARE_PROFILES at or above it), ``response_delay`` (seconds, or a
    (low, high) range drawn per request; the document allows up to 0.5 s),
    ``humidity_tenths`` (default unit of every channel), ``channels`` (a
    list of :class:`Channel` replacing the seeded layout), ``dynamic``
    (False: no offline episodes from the value model).
    """

    kind = "hub"
    busy_code = ExceptionCode.DEVICE_FAILURE  #: [HUB] 2.3.2.3: 04 "Device is busy"
    REPORT_PERIOD_S: ClassVar[float] = 2.0  #: each channel's sensor reports this often
    OFFLINE_WINDOW_S: ClassVar[float] = 300.0
    OFFLINE_PROBABILITY: ClassVar[float] = 0.04  #: per channel and window

    def __init__(
        self,
        address: int = HUB.default_address,
        *,
        baud: int = HUB.default_baud,
        seed: int = 0,
        clock: SimClock | None = None,
        firmware: str = max(HUB_FIRMWARE_PROFILES, key=parse_firmware),
        response_delay: float | tuple[float, float] = 0.0,
        humidity_tenths: bool = True,
        channels: Sequence[Channel] | None = None,
        dynamic: bool = True,
    ) -> None:
        if not _HUB_ADDRESSES[0] <= address <= _HUB_ADDRESSES[1]:
            raise InvalidArgument(f"hub address must be {_HUB_ADDRESSES[0]}.."
                                  f"{_HUB_ADDRESSES[1]}, got {address}")
        lo, hi = response_delay if isinstance(response_delay, tuple) else (response_delay,) * 2
        if not 0 <= lo <= hi:
            raise InvalidArgument(f"response_delay must be seconds >= 0 (or a low, high "
                                  f"range), got {response_delay!r}")
        super().__init__(address, baud=baud, seed=seed, clock=clock)
        self.response_delay = response_delay
        self.dynamic = dynamic
        n = HUB.channels
        self._first = HUB.first
        self._image = array("H", bytes(2 * HUB.count))
        self._offsets = tuple(b.first - HUB.first for b in HUB.blocks)
        self._supported = bytearray(HUB.count)
        self._firmware = ""
        self._profile_channels = n
        self._profile_blocks: frozenset[str] = frozenset()
        if channels is not None and len(channels) != n:
            raise InvalidArgument(f"channels must list {n} Channel entries, got {len(channels)}")
        self._channels = list(channels) if channels is not None else [
            self._seeded_channel(ci, humidity_tenths) for ci in range(n)]
        self._models = [self._seeded_model(ci) for ci in range(n)]
        order = sorted(range(n), key=lambda ci: self._models[ci].phase)
        self._by_phase = order
        self._phases = [self._models[ci].phase for ci in order]
        self._pins: dict[tuple[int, int], int] = {}  # (block index, channel index) -> raw
        self._forced: dict[int, bool] = {}  # channel index -> offline (True) / online
        self._offline_until: dict[int, float] = {}  # channel index -> simulated expiry
        self._episodes = [(-1, 0.0, 0.0)] * n  # channel index -> (window, start, end)
        self._refreshed: float | None = None
        self.firmware = firmware
        self._refresh()

    # -- configuration -----------------------------------------------------------------

    @property
    def firmware(self) -> str:
        """The firmware version; setting it switches the register profile."""
        return self._firmware

    @firmware.setter
    @_locked
    def firmware(self, version: str) -> None:
        want = parse_firmware(version)
        profiles = _profiles()
        chosen = next((p for p in profiles if want <= p[0]), profiles[-1])
        _, channels, blocks = chosen
        unknown = blocks - {b.name for b in HUB.blocks}
        if unknown:
            raise InvalidArgument(f"firmware profile names unknown blocks {sorted(unknown)}")
        sup = bytearray(HUB.count)
        for b in HUB.blocks:
            if b.name in blocks:
                off = b.first - HUB.first
                sup[off:off + channels] = b"\x01" * channels
        self._supported = sup
        self._profile_channels = channels
        self._profile_blocks = blocks
        self._firmware = version.strip().lstrip("vV")

    @property
    def channels(self) -> int:
        """Channels the firmware serves (50 on V1.07 and below, else 100)."""
        return self._profile_channels

    def supports(self, block: str) -> bool:
        """True when the firmware has ``block`` (a HUB block name)."""
        return block in self._profile_blocks

    def channel(self, channel: int) -> Channel:
        """The configuration of ``channel`` (1-based); a copy."""
        c = self._channels[self._ci(channel)]
        return Channel(**{f.name: getattr(c, f.name) for f in fields(Channel)})

    @_locked
    def configure(self, channel: int | Iterable[int] | None = None, **flags: bool) -> None:
        """Change what is plugged into ``channel`` (1-based, several, or
        None for all): ``present``, ``temperature``, ``humidity``,
        ``pressure``, ``temperature2``, ``humidity_tenths`` (see :class:`Channel`)."""
        names = {f.name for f in fields(Channel)}
        bad = set(flags) - names
        if bad:
            raise InvalidArgument(f"unknown channel flags {sorted(bad)}; use {sorted(names)}")
        for ci in self._cis(channel):
            for k, v in flags.items():
                setattr(self._channels[ci], k, bool(v))
            self._update(ci, self.clock.now())

    def set_humidity_unit(self, channel: int | Iterable[int] | None, unit_pct: float) -> None:
        """Humidity unit of ``channel`` (or all): 0.1 or 1 (percent)."""
        if unit_pct not in (0.1, 1, 1.0):
            raise InvalidArgument(f"humidity unit is 0.1 or 1 (%), got {unit_pct!r}")
        self.configure(channel, humidity_tenths=unit_pct == 0.1)

    @property
    def humidity_tenths(self) -> bytes:
        """One byte per channel, 1 where the humidity unit is 0.1 % (the
        decoder's ``humidity_tenths`` argument)."""
        return bytes(1 if c.humidity_tenths else 0 for c in self._channels)

    # -- test hooks -------------------------------------------------------------------------

    @_locked
    def pin(self, block: str, channel: int, raw: int) -> None:
        """Make ``block``'s register of ``channel`` read ``raw`` until :meth:`unpin`."""
        b = self._block(block)
        ci = self._ci(channel)
        self._pins[(b.index, ci)] = raw & 0xFFFF
        self._update(ci, self.clock.now())

    @_locked
    def unpin(self, block: str | None = None, channel: int | None = None) -> None:
        """Drop pins (all, one block's, or one register's)."""
        for key in list(self._pins):
            if (block is None or key[0] == self._block(block).index) and (
                    channel is None or key[1] == self._ci(channel)):
                del self._pins[key]
                self._update(key[1], self.clock.now())

    @_locked
    def set_offline(self, channel: int | Iterable[int], offline: bool | None = True,
                    seconds: float | None = None) -> None:
        """Force ``channel`` offline (True), online (False, no episodes) or
        back to the value model (None); with ``seconds``, offline for that
        long in simulated time."""
        now = self.clock.now()
        for ci in self._cis(channel):
            if seconds is not None and offline:
                self._offline_until[ci] = now + seconds
            elif offline is None:
                self._forced.pop(ci, None)
                self._offline_until.pop(ci, None)
            else:
                self._forced[ci] = bool(offline)
                self._offline_until.pop(ci, None)
            self._update(ci, now)

    @_locked
    def registers(self, address: int = HUB.first, count: int = HUB.count) -> array[int]:
        """The register image now (whatever the firmware lacks included)."""
        self._refresh()
        i = address - self._first
        return self._image[i:i + count]

    @_locked
    def raw(self, block: str, channel: int) -> int:
        """The raw register of ``block`` for ``channel`` now."""
        self._refresh()
        return self._image[self._offsets[self._block(block).index] + self._ci(channel)]

    @_locked
    def sensor_fault(self, rng: random.Random, seconds: float, *, bits: int | None = None,
                     channels: Sequence[int] | None = None) -> str:
        """Take ``channels`` (default: one present channel) offline for ``seconds``."""
        if not channels:
            present = [ci + 1 for ci in range(self._profile_channels)
                       if self._channels[ci].present] or [1]
            channels = [rng.choice(present)]
        self.set_offline(channels, True, seconds)
        return f"channels {', '.join(map(str, channels))} offline for {seconds:g} s"

    @_locked
    def idle(self) -> None:
        """Refresh the channels that reported since the last request."""
        self._refresh()

    def turnaround(self) -> float:
        """``response_delay``, drawn from its range when it is one."""
        d = self.response_delay
        if isinstance(d, tuple):
            return self.rng.uniform(d[0], d[1])
        return d

    # -- requests ---------------------------------------------------------------------------

    def handle(self, pdu: bytes) -> bytes | None:
        """Answer one request PDU as [HUB] and [NOTES] say."""
        fc = pdu[0]
        if fc not in HUB.function_codes:
            return exception_pdu(fc, ExceptionCode.ILLEGAL_FUNCTION)
        if len(pdu) != 5:
            return exception_pdu(fc, ExceptionCode.ILLEGAL_DATA_ADDRESS)
        i = ((pdu[1] << 8) | pdu[2]) - self._first
        n = (pdu[3] << 8) | pdu[4]
        if not (1 <= n <= HUB.max_read and i >= 0 and i + n <= HUB.count) or \
                self._supported.find(0, i, i + n) != -1:
            return exception_pdu(fc, ExceptionCode.ILLEGAL_DATA_ADDRESS)
        self._refresh()
        return bytes((fc, 2 * n)) + _swapped(self._image[i:i + n])

    def describe(self) -> str:
        present = sum(1 for c in self._channels[:self._profile_channels] if c.present)
        return (f"hub at address {self.address} ({self.baud} 8N1), firmware "
                f"{self.firmware} ({self._profile_channels} channels, "
                f"{len(self._profile_blocks)} blocks), {present} sensors")

    # -- the value model -------------------------------------------------------------------

    def _ci(self, channel: int) -> int:
        if not 1 <= channel <= HUB.channels:
            raise InvalidArgument(f"channel must be 1..{HUB.channels}, got {channel!r}")
        return channel - 1

    def _cis(self, channel: int | Iterable[int] | None) -> list[int]:
        if channel is None:
            return list(range(HUB.channels))
        if isinstance(channel, int):
            return [self._ci(channel)]
        return [self._ci(c) for c in channel]

    @staticmethod
    def _block(name: str) -> Block:
        try:
            return HUB.block(name)
        except KeyError:
            raise InvalidArgument(
                f"unknown block {name!r}; use one of {', '.join(b.name for b in HUB.blocks)}"
            ) from None

    def _seeded_channel(self, ci: int, tenths: bool) -> Channel:
        u = _noise(self.seed, 100, ci)
        if u < 0.10:
            return Channel(present=False, humidity_tenths=tenths)
        if u < 0.55:  # temperature and humidity
            return Channel(humidity_tenths=tenths)
        if u < 0.75:  # temperature only
            return Channel(humidity=False, humidity_tenths=tenths)
        if u < 0.85:  # two probes
            return Channel(humidity=False, temperature2=True, humidity_tenths=tenths)
        return Channel(temperature=False, humidity=False, pressure=True,  # pressure sensor
                       humidity_tenths=tenths)

    def _seeded_model(self, ci: int) -> _Model:
        s = self.seed

        def u(salt: int) -> float:
            return _noise(s, 200 + salt, ci)

        freezer = u(1) < 0.25  # some channels sit in a freezer: negative temperatures
        temp = -180.0 - 70.0 * u(2) if freezer else 150.0 + 150.0 * u(2)
        return _Model(
            key=_mix(_mix(s & _M64) ^ ci),
            phase=self.REPORT_PERIOD_S * u(0),
            temp=temp,
            temp_amp=5.0 + 25.0 * u(3),
            temp_period=600.0 + 3000.0 * u(4),
            humidity=300.0 + 400.0 * u(5),
            p_temp=180.0 + 120.0 * u(6),
            pressure=95.0 + 10.0 * u(7) if u(8) < 0.5 else 200.0 + 400.0 * u(7),
            volt=3000.0 + 600.0 * u(9),
            rssi=-45.0 - 50.0 * u(10),
            temp2=temp + 20.0 * (u(11) - 0.5),
        )

    def _offline(self, ci: int, t: float) -> bool:
        forced = self._forced.get(ci)
        if forced is not None:
            return forced
        if ci in self._offline_until:
            return True
        if not self.dynamic:
            return False
        w = int(t // self.OFFLINE_WINDOW_S)
        episode = self._episodes[ci]
        if episode[0] != w:  # one offline episode at most per window, drawn once
            key = self._models[ci].key
            start = end = 0.0
            if _noise(key, 300, w) < self.OFFLINE_PROBABILITY:
                length = 5.0 + 55.0 * _noise(key, 301, w)
                start = w * self.OFFLINE_WINDOW_S + (self.OFFLINE_WINDOW_S - length) * _noise(
                    key, 302, w)
                end = start + length
            episode = self._episodes[ci] = (w, start, end)
        return episode[1] <= t < episode[2]

    def _values(self, ci: int, t: float) -> list[int]:
        """The channel's raw registers, block by block, at its last report before ``t``."""
        m = self._models[ci]
        c = self._channels[ci]
        k = math.floor((t - m.phase) / self.REPORT_PERIOD_S)
        tk = m.phase + k * self.REPORT_PERIOD_S
        if not c.present or self._offline(ci, tk):
            return _ALL_OFFLINE
        h = _mix(m.key ^ (k & _M64))  # one hash per report: 8 bits of noise each below
        wave = math.sin(_TWO_PI * tk / m.temp_period + ci)
        tenths = c.humidity_tenths
        humidity = min(1000.0, max(0.0, m.humidity - 60.0 * wave
                                   + 8.0 * ((h & 0xFF) / 256.0 - 0.5)))
        value = {
            "temperature_c": sign_magnitude(round(
                m.temp + m.temp_amp * wave + 3.0 * ((h >> 8 & 0xFF) / 256.0 - 0.5))),
            "humidity_pct": round(humidity) if tenths else round(humidity / 10.0),
            "pressure_temperature_c": sign_magnitude(round(
                m.p_temp + 0.5 * m.temp_amp * wave + 2.0 * ((h >> 16 & 0xFF) / 256.0 - 0.5))),
            "pressure_kpa": max(0, round(m.pressure * (1.0 + 0.02 * wave)
                                         + (h >> 24 & 0xFF) / 256.0 - 0.5)),
            "voltage_mv": max(0, round(m.volt - 10.0 * tk / 86400.0
                                       + 6.0 * ((h >> 32 & 0xFF) / 256.0 - 0.5))),
            # RSSI stays at -2 dBm or below, so it never reads as 0xFFFF
            "rssi_dbm": round(m.rssi + 6.0 * ((h >> 40 & 0xFF) / 256.0 - 0.5)) & 0xFFFF,
            "temperature2_c": sign_magnitude(round(
                m.temp2 + m.temp_amp * wave + 3.0 * ((h >> 48 & 0xFF) / 256.0 - 0.5))),
        }
        return [value[name] if getattr(c, sensor) else
                (_NO_HUMIDITY[tenths] if name == "humidity_pct" else _OFFLINE)
                for name, sensor in _BLOCK_SENSORS]

    def _update(self, ci: int, t: float) -> None:
        img, offs = self._image, self._offsets
        for bi, raw in enumerate(self._values(ci, t)):
            img[offs[bi] + ci] = raw
        if self._pins:
            for (bi, pci), raw in self._pins.items():
                if pci == ci:
                    img[offs[bi] + ci] = raw

    def _refresh(self) -> None:
        """Bring the image to now: only the channels that reported since the
        last refresh are recomputed (each channel reports every
        REPORT_PERIOD_S at its own phase)."""
        t = self.clock.now()
        last = self._refreshed
        if last == t:
            return
        period = self.REPORT_PERIOD_S
        if last is None or t < last or t - last >= period:
            changed: Iterable[int] = range(HUB.channels)
        else:
            a, b = last % period, t % period
            lo = bisect.bisect_right(self._phases, a)
            hi = bisect.bisect_right(self._phases, b)
            changed = (self._by_phase[lo:hi] if a <= b
                       else self._by_phase[lo:] + self._by_phase[:hi])
        if self._offline_until:
            for ci, until in list(self._offline_until.items()):
                if until <= t:
                    del self._offline_until[ci]
                    self._update(ci, t)
        for ci in changed:
            self._update(ci, t)
        self._refreshed = t
