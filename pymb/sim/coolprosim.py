"""The CoolPro's behaviours over its map (``coolpro``): the map sets the
registers, addresses, exceptions and write rules; this adds its telemetry as
a deterministic function of seed and simulated time, its status episodes,
and its reset (the stored address and baud take effect, uptime restarts)."""

from __future__ import annotations

import calendar
import math
import random
from collections.abc import Sequence
from typing import ClassVar

from pymb import maps
from pymb.errors import InvalidArgument
from pymb.maps import Point
from pymb.sim.base import _TWO_PI, _locked, _noise, parse_firmware
from pymb.sim.clock import SimClock
from pymb.sim.mapsim import MapSimDevice

__all__ = ["BAUD_RATES", "CoolProDevice"]

_MAP = maps.builtin("coolpro")
#: the baud rates by index (the map's ``baud_rate_index`` values)
BAUD_RATES = tuple(int(v) for _, v in sorted(_MAP.points["baud_rate_index"].values.items()))
_BIT = {name: 1 << bit for bit, name in _MAP.points["status"].flags.items()}
#: status bit -> telemetry points that read 0 while it is raised
_FAULT_ZEROES = {
    _BIT["INPUT_MEASUREMENT_FAULT"]: ("input_voltage_v", "input_current_a"),
    _BIT["OUTPUT_MEASUREMENT_FAULT"]: ("output_voltage_v", "output_current_a"),
    _BIT["TEMPERATURE_SENSOR_FAULT"]: ("temperature_c",),
}
#: bits the value model raises now and then, with their weights
_EPISODE_BITS = ((_BIT["INPUT_MEASUREMENT_FAULT"], 3), (_BIT["OUTPUT_MEASUREMENT_FAULT"], 3),
                 (_BIT["TEMPERATURE_SENSOR_FAULT"], 3), (_BIT["CALIBRATION_INVALID"], 1))
_TELEMETRY = tuple(p.name for p in _MAP.points.values() if p.group == "telemetry")


class CoolProDevice(MapSimDevice):
    """The CoolPro power-supply monitor of its map (``coolpro``).

    Holding registers (FC 0x03 read, 0x06 write): device address, baud index,
    reset. A write is echoed and stored; the stored address and baud take
    effect at the next reset (writing the reset register's one valid value,
    echoed first). Input registers (FC 0x04): telemetry in milliunits and the
    identity block. Other functions answer 01, a quantity outside 1..125 or a
    write outside ``valid`` 03, a range outside the map 02.

    Options: ``gap`` (seconds before each reply; the map's turnaround, 0 for
    benchmarks), ``serial_number`` (default 12345 plus the distance of
    ``address`` from 40), ``hardware_revision``, ``firmware`` (major, minor,
    patch), ``manufactured`` (Unix time), ``uptime`` (seconds already up),
    ``startup_seconds`` (SYSTEM_STARTUP after a reset), ``dynamic`` (False:
    no status-fault episodes).
    """

    functions = frozenset((3, 4, 6))
    LOAD_STEP_S: ClassVar[float] = 20.0  #: how often the load may change
    EPISODE_WINDOW_S: ClassVar[float] = 600.0  #: one status-fault episode chance per window
    EPISODE_PROBABILITY: ClassVar[float] = 0.25
    DAILY_RESET_S: ClassVar[int] = 86400  #: uptime wraps and DAILY_RESET is raised

    def __init__(
        self,
        address: int = _MAP.device.default_address,
        *,
        baud: int = BAUD_RATES[0],
        seed: int = 0,
        clock: SimClock | None = None,
        gap: float = _MAP.timing.turnaround,
        serial_number: int | None = None,
        hardware_revision: int = 1,
        firmware: tuple[int, int, int] | str = (1, 0, 0),
        manufactured: int = calendar.timegm((2026, 6, 1, 0, 0, 0, 0, 0, 0)),
        uptime: float = 0.0,
        startup_seconds: float = 2.0,
        dynamic: bool = True,
    ) -> None:
        if baud not in BAUD_RATES:
            raise InvalidArgument(f"coolpro baud must be one of {', '.join(map(str, BAUD_RATES))}"
                                  f", got {baud}")
        if gap < 0:
            raise InvalidArgument(f"gap must be 0 or more seconds, got {gap!r}")
        fw = parse_firmware(firmware) if isinstance(firmware, str) else tuple(firmware)
        if len(fw) != 3:
            raise InvalidArgument(f"coolpro firmware is major.minor.patch, got {firmware!r}")
        self.startup_seconds = float(startup_seconds)
        self.resets = 0  #: resets done (commands and :meth:`reset`)
        self._pins: dict[str, int] = {}
        self._forced: dict[int, float] = {}  # status mask -> simulated expiry
        self._boot = 0.0
        super().__init__(_MAP, address, baud=baud, seed=seed, clock=clock, dynamic=dynamic,
                         delay=gap, firmware=".".join(map(str, fw)))
        if serial_number is None:
            serial_number = (12345 + address - _MAP.device.default_address) & 0xFFFFFFFF
        for name, value in (("address", address), ("baud_rate_index", BAUD_RATES.index(baud)),
                            ("serial_number", serial_number),
                            ("hardware_revision", hardware_revision), ("firmware_major", fw[0]),
                            ("firmware_minor", fw[1]), ("firmware_patch", fw[2]),
                            ("manufactured", manufactured)):
            self._put_raw(name, value)
        self._boot = self.clock.now() - float(uptime)

    def _start(self, rng: random.Random) -> None:
        """Every register starts at 0; the constructor and the model set them."""

    @property
    def gap(self) -> float:
        """Seconds from a request's end to the reply."""
        return self.delay

    def register(self, name: str) -> int:
        """The raw value of a point of the map by name, as a read now would
        return it (32-bit points combined)."""
        return self.raw(name)

    @property
    def pending_address(self) -> int:
        """The address stored by the last write, in effect after a reset."""
        return self.raw("address")

    @property
    def pending_baud(self) -> int:
        """The baud rate stored by the last write, in effect after a reset."""
        return BAUD_RATES[self.raw("baud_rate_index")]

    @property
    def uptime(self) -> float:
        """Seconds since the last reset (simulated)."""
        return self.clock.now() - self._boot

    # -- test hooks ---------------------------------------------------------------

    @_locked
    def pin(self, name: str, raw: int) -> None:
        """Make telemetry point ``name`` read ``raw`` until :meth:`unpin`."""
        if name not in _TELEMETRY:
            raise InvalidArgument(f"{name} is not a telemetry point; pin one of "
                                  f"{', '.join(_TELEMETRY)}")
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
            if self._point(name)[0].group != "identity":
                raise InvalidArgument(f"{name} is not an identity point")
            self._put_raw(name, value)

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
        self._address = self.raw("address")
        self._baud = BAUD_RATES[self.raw("baud_rate_index")]
        self._boot = self.clock.now()
        self.resets += 1

    def _wrote(self, p: Point, channel: int) -> None:
        if p.name == "reset":  # it always reads 0; the echo still goes from the old address
            self._put_raw("reset", 0)
            self.reset()

    @_locked
    def sensor_fault(self, rng: random.Random, seconds: float, *, bits: int | None = None,
                     channels: Sequence[int] | None = None) -> str:
        """Raise one measurement-fault bit (or ``bits``) for ``seconds``."""
        mask = bits if bits else rng.choice(tuple(_FAULT_ZEROES))
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
            bits |= _BIT["SYSTEM_STARTUP"]
        if up >= self.DAILY_RESET_S:
            bits |= _BIT["DAILY_RESET"]
        if self.dynamic:
            bits |= self._episode(t)
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

    def _refresh(self) -> None:
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
        status = self.status(t)
        values = {"input_voltage_v": vin, "input_current_a": iin, "output_voltage_v": vout,
                  "output_current_a": iout, "temperature_c": temp}
        for bit, names in _FAULT_ZEROES.items():
            if status & bit:
                for name in names:
                    values[name] = 0.0
        img = self._images["input"]
        for name, v in values.items():
            img[_MAP.points[name].address] = max(0, min(0xFFFF, round(v)))
        self._put_raw("uptime_s", int(max(0.0, t - self._boot)) % self.DAILY_RESET_S)
        self._put_raw("status", status)
        for name, raw in self._pins.items():
            self._put_raw(name, raw)

    def describe(self) -> str:
        """One line for the command line's banner."""
        fw = ".".join(str(self.raw(n)) for n in ("firmware_major", "firmware_minor",
                                                 "firmware_patch"))
        return (f"coolpro at address {self.address} ({self.baud} 8N1), serial "
                f"{self.raw('serial_number')}, firmware {fw}, gap {self.gap * 1000:g} ms")
