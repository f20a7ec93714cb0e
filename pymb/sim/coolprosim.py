"""The CoolPro's behaviours over its map (``coolpro``): the map sets the
registers, addresses, exceptions, write rules and identity values (each
point's ``example``); this adds its telemetry as a deterministic function of
seed and simulated time, its status flags, and its reset (the stored address
and baud take effect, uptime restarts)."""

from __future__ import annotations

import math
import random
from collections.abc import Callable, Sequence
from typing import ClassVar

from pymb import maps
from pymb.errors import InvalidArgument
from pymb.maps import Point
from pymb.sim.base import (
    _TWO_PI,
    MAX_DELAY_S,
    Keys,
    _locked,
    _noise,
    episode,
    parse_firmware,
    seconds,
)
from pymb.sim.clock import SimClock
from pymb.sim.mapsim import MapSimDevice

__all__ = ["BAUD_RATES", "CoolProDevice"]

_MAP = maps.builtin("coolpro")
#: the baud rates by index (the map's ``baud_rate_index`` values)
BAUD_RATES = tuple(int(v) for _, v in sorted(_MAP.points["baud_rate_index"].values.items()))
_BIT = {name: 1 << bit for bit, name in _MAP.points["status"].flags.items()}
#: status bit -> telemetry points that read 0 while it is raised
_ZEROES = {_BIT["INPUT_MEASUREMENT_FAULT"]: ("input_voltage_v", "input_current_a"),
           _BIT["OUTPUT_MEASUREMENT_FAULT"]: ("output_voltage_v", "output_current_a"),
           _BIT["TEMPERATURE_SENSOR_FAULT"]: ("temperature_c",)}
#: bits the value model raises now and then (the last a third as often)
_EPISODES = (*(bit for bit in _ZEROES for _ in range(3)), _BIT["CALIBRATION_INVALID"])
_FIRMWARE = ".".join(str(_MAP.points[f"firmware_{k}"].example) for k in ("major", "minor", "patch"))


def _whole(high: int) -> Callable[[str], int]:
    """A parser of a whole number 0..``high`` (decimal or 0x hex)."""
    def parse(value: str) -> int:
        n = int(value, 0)
        if not 0 <= n <= high:
            raise ValueError(value)
        return n
    return parse


def _uptime(value: str) -> float:
    s = float(value)
    if not 0 <= s <= 0xFFFFFFFF:  # NaN too: the register counts seconds
        raise ValueError(value)
    return s


class CoolProDevice(MapSimDevice):
    """The CoolPro power-supply monitor of its map (``coolpro``).

    Holding registers (FC 0x03 read, 0x06 write): device address, baud index,
    reset. A write is echoed and stored; the stored address and baud take
    effect at the next reset (writing the reset register's one valid value,
    echoed first). Input registers (FC 0x04): telemetry in milliunits and the
    identity block. Other functions answer 01, a quantity outside 1..125 or a
    write outside ``valid`` 03, a range outside the map 02.

    Options: ``gap`` (seconds before each reply; the map's turnaround, 0 for
    benchmarks), ``serial_number`` (default the map's plus the distance of
    ``address`` from the default address), ``hardware_revision``,
    ``firmware`` (major.minor.patch), ``manufactured`` (Unix time; these
    three default to the map's examples), ``uptime`` (seconds already up),
    ``startup_seconds`` (SYSTEM_STARTUP after a reset), ``dynamic`` (False:
    no status-fault episodes).
    """

    functions = frozenset((3, 4, 6))
    builtin_map = _MAP
    spec_keys: ClassVar[Keys] = {
                 "gap": ("delay", seconds, f"0..{MAX_DELAY_S:g} seconds before each reply"),
                 "serial": ("serial_number", _whole(0xFFFFFFFF), "a number 0..4294967295"),
                 "hardware": ("hardware_revision", _whole(0xFFFF), "a number 0..65535"),
                 "uptime": ("uptime", _uptime, "0..4294967295 seconds")}
    delay_arg: ClassVar[str] = "gap"
    LOAD_STEP_S: ClassVar[float] = 20.0  #: how often the load may change
    EPISODE_WINDOW_S: ClassVar[float] = 600.0  #: one status-fault episode chance per window
    EPISODE_PROBABILITY: ClassVar[float] = 0.25
    DAILY_RESET_S: ClassVar[int] = 86400  #: uptime wraps and DAILY_RESET is raised

    def __init__(self, address: int = _MAP.device.default_address, *, baud: int = BAUD_RATES[0],
                 seed: int = 0, clock: SimClock | None = None,
                 gap: float = _MAP.timing.turnaround, serial_number: int | None = None,
                 hardware_revision: int | None = None,
                 firmware: tuple[int, int, int] | str = _FIRMWARE,
                 manufactured: int | None = None, uptime: float = 0.0,
                 startup_seconds: float = 2.0, dynamic: bool = True) -> None:
        if baud not in BAUD_RATES:
            raise InvalidArgument(f"coolpro baud must be one of {', '.join(map(str, BAUD_RATES))}"
                                  f", got {baud}")
        fw = parse_firmware(firmware)
        if len(fw) != 3:
            raise InvalidArgument(f"coolpro firmware is major.minor.patch, got {firmware!r}")
        self.startup_seconds = float(startup_seconds)
        self.resets = 0  #: resets done (commands and :meth:`reset`)
        self._boot = 0.0
        super().__init__(_MAP, address, baud=baud, seed=seed, clock=clock, dynamic=dynamic,
                         delay=gap, firmware=".".join(map(str, fw)))
        if serial_number is None:
            serial_number = int(_MAP.points["serial_number"].example)  # type: ignore[arg-type]
            serial_number = (serial_number + address - _MAP.device.default_address) & 0xFFFFFFFF
        for name, value in (("address", address), ("baud_rate_index", BAUD_RATES.index(baud)),
                            ("reset", 0), ("serial_number", serial_number),
                            ("hardware_revision", hardware_revision), ("firmware_major", fw[0]),
                            ("firmware_minor", fw[1]), ("firmware_patch", fw[2]),
                            ("manufactured", manufactured)):
            if value is not None:
                self._put_raw(name, value)
        self._boot = self.clock.now() - float(uptime)

    @property
    def gap(self) -> float:
        """Seconds from a request's end to the reply."""
        return self.turnaround()

    def register(self, name: str) -> int:
        """The raw value of a point by name, as a read now returns it."""
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

    def set_status(self, mask: int, seconds: float | None = None) -> None:
        """Raise the status bits in ``mask`` (reserved bits 7..15 too), for
        ``seconds`` of simulated time or until :meth:`clear_status`."""
        self.set_flags("status", mask, seconds)

    def clear_status(self, mask: int = 0xFFFF) -> None:
        """Drop bits raised by :meth:`set_status` (the model's own stay)."""
        self.clear_flags("status", mask)

    @_locked
    def reset(self) -> None:
        """Reset the device: the stored address and baud take effect, uptime
        restarts at 0 and SYSTEM_STARTUP is raised for ``startup_seconds``."""
        self._address, self._baud = self.pending_address, self.pending_baud
        self._boot = self.clock.now()
        self.resets += 1

    def _wrote(self, p: Point, channel: int) -> None:
        if p.name == "reset":  # it always reads 0; the echo still goes from the old address
            self._put_raw("reset", 0)
            self.reset()

    def sensor_fault(self, rng: random.Random, seconds: float, *, bits: int | None = None,
                     channels: Sequence[int] | None = None) -> str:
        """Raise one measurement-fault bit (or ``bits``) for ``seconds``."""
        mask = bits if bits else rng.choice(tuple(_ZEROES))
        self.set_status(mask, seconds)
        return f"status 0x{mask:04X} for {seconds:g} s"

    # -- the value model -------------------------------------------------------------

    @_locked
    def status(self, t: float | None = None) -> int:
        """The status flags at simulated time ``t`` (default now)."""
        t = self.clock.now() if t is None else t
        up = t - self._boot
        bits = (_BIT["SYSTEM_STARTUP"] if up < self.startup_seconds else 0) | (
            _BIT["DAILY_RESET"] if up >= self.DAILY_RESET_S else 0)
        # one chance per window of a fault episode of 5..45 s, somewhere in it
        w = int(t // self.EPISODE_WINDOW_S)
        ep = episode(self.seed, 11, w, self.EPISODE_WINDOW_S, self.EPISODE_PROBABILITY, 45.0) \
            if self.dynamic else None
        if ep is not None and ep[0] <= t < ep[1]:
            bits |= _EPISODES[int(_noise(self.seed, 14, w) * len(_EPISODES))]
        return bits | self._raised("status", t)

    def _load_ma(self, step: int) -> float:
        levels = (1500.0, 2400.0, 3200.0, 3200.0, 4100.0, 5600.0)
        return levels[int(_noise(self.seed, 1, step) * len(levels))]

    def _refresh(self) -> None:
        t = self.clock.now()
        tq = math.floor(t * 10.0) / 10.0  # the device measures at 10 Hz
        tick, s = int(tq * 10.0), self.seed
        # Load steps every LOAD_STEP_S, settling over half a second.
        step = int(tq // self.LOAD_STEP_S)
        new, old = self._load_ma(step), self._load_ma(step - 1)
        settle = min(1.0, (tq - step * self.LOAD_STEP_S) / 0.5)
        load = old + (new - old) * settle
        iout = load + 20.0 * math.sin(_TWO_PI * tq / 7.3) + 16.0 * (_noise(s, 2, tick) - 0.5)
        vout = 24000.0 - 0.01 * (iout - 3200.0) + 4.0 * math.sin(_TWO_PI * tq * 1.7)
        vin = 24500.0 - 0.05 * (iout - 3200.0) + 55.0 * math.sin(_TWO_PI * tq * 1.37) + 20.0 * (
            _noise(s, 3, tick) - 0.5)
        temp = 25800.0 + 0.9 * (load - 3200.0) + 30.0 * (_noise(s, 5, tick) - 0.5) \
            + 1500.0 * math.sin(_TWO_PI * t / 3600.0 + _TWO_PI * _noise(s, 4))
        status = self.status(t)
        values = {"input_voltage_v": vin, "input_current_a": iout * vout / (vin * 0.964),
                  "output_voltage_v": vout, "output_current_a": iout, "temperature_c": temp}
        for bit, names in _ZEROES.items():
            if status & bit:
                values.update(dict.fromkeys(names, 0.0))
        for name, v in values.items():
            self._put_raw(name, max(0, min(0xFFFF, round(v))))
        self._put_raw("uptime_s", int(max(0.0, t - self._boot)) % self.DAILY_RESET_S)
        self._put_raw("status", status)

    def describe(self) -> str:
        """One line for the command line's banner."""
        return (f"coolpro at address {self.address} ({self.baud} 8N1), serial "
                f"{self.raw('serial_number')}, firmware {self.firmware}, "
                f"gap {self.gap * 1000:g} ms")
