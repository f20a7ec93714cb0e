"""The simulated CoolPro: its registers, its write semantics (address and
baud at reset), its telemetry as a deterministic function of seed and
simulated time, and its status episodes."""

from __future__ import annotations

import calendar
import math
import random
from array import array
from collections.abc import Sequence
from typing import ClassVar

from pymb.devices.maps import (
    COOLPRO,
    COOLPRO_BAUD_RATES,
    COOLPRO_GAP_S,
    COOLPRO_RESET_VALUE,
    COOLPRO_STATUS_BITS,
    Access,
    Register,
    Type,
)
from pymb.errors import (
    InvalidArgument,
)
from pymb.sim.base import (
    _MAX_READ,
    _TWO_PI,
    Device,
    ExceptionCode,
    Function,
    _locked,
    _noise,
    _swapped,
    exception_pdu,
    parse_firmware,
)
from pymb.sim.clock import SimClock

__all__ = ["CoolProDevice"]


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
