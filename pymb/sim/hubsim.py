"""The sensor hub's behaviours over its map (``hub``): the map sets the
registers, blocks, markers, addresses and the firmware each block needs; this
adds the hub's one firmware rule the map cannot say (V1.07 and below: 50
channels of temperature and humidity only), what is plugged into each
channel (per-channel humidity units), and the values of each channel as a
deterministic function of seed and simulated time (a model per channel)."""

from __future__ import annotations

import bisect
import math
import random
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, fields, replace
from typing import ClassVar

from pymb import maps
from pymb.devices.mapspec import MapTarget
from pymb.errors import InvalidArgument
from pymb.maps import Point
from pymb.sim.base import (
    _M64,
    _TWO_PI,
    ExceptionCode,
    Keys,
    _locked,
    _mix,
    _noise,
    episode,
    parse_firmware,
    sign_magnitude,
)
from pymb.sim.clock import SimClock
from pymb.sim.mapsim import MapSimDevice

__all__ = ["Channel", "HubDevice"]

_MAP = maps.builtin("hub")
_BLOCKS = tuple(_MAP.points.values())
_ADDRESS = tuple(p.address for p in _BLOCKS)  # each block's first register
_N = max(p.channels for p in _BLOCKS)
#: V1.07 and below serve 50 channels (of the blocks without a min_firmware)
_LEGACY = ((1, 7), 50)
_LATEST = max((p.min_firmware for p in _BLOCKS if p.min_firmware), key=parse_firmware)


def _marker(p: Point, state: str) -> int:
    return next(raw for raw, name in p.markers.items() if name == state)


_OFFLINE = _marker(_BLOCKS[0], "offline")
_NO_HUMIDITY = {unit == 0.1: _marker(_MAP.configure(humidity_unit=unit).points["humidity_pct"],
                                     "no_sensor") for unit in (1, 0.1)}


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


#: which Channel flag each block needs, in the map's order
_SENSORS = tuple({"temperature_c": "temperature", "humidity_pct": "humidity",
                  "pressure_temperature_c": "pressure", "pressure_kpa": "pressure",
                  "voltage_mv": "present", "rssi_dbm": "present",
                  "temperature2_c": "temperature2"}[p.name] for p in _BLOCKS)


class HubDevice(MapSimDevice):
    """The 100-channel sensor hub of its map (``hub``).

    FC 0x03 only (0x10 answers 0x90/01, any other function 01); a read of
    1..125 registers that touches only registers the firmware has, else 02;
    addresses 1..255; broadcasts are never answered.

    Options: ``firmware`` (a version: blocks need their ``min_firmware``;
    V1.07 and below has 50 channels of temperature and humidity),
    ``response_delay`` (seconds, or a (low, high) range drawn per request;
    the document allows up to 0.5 s), ``humidity_tenths`` (default unit of
    every channel), ``channels`` (a list of :class:`Channel` replacing the
    seeded layout), ``dynamic`` (False: no offline episodes).
    """

    functions = frozenset((3,))
    bad_request = ExceptionCode.ILLEGAL_DATA_ADDRESS  # [HUB]: every refused read is 02
    answers_readable = False  # only the blocks the firmware has
    builtin_map = _MAP
    #: ``humidity``: the humidity unit of every channel (as the map's ``humidity_unit``)
    spec_keys: ClassVar[Keys] = {
        "humidity": ("humidity_tenths", lambda v: {"0.1": True, "1": False}[v], "0.1 or 1")}
    delay_arg: ClassVar[str] = "response_delay"
    refused: ClassVar[Mapping[str, str]] = {
        "channels": "a simulated hub's channel count follows its firmware (firmware=1.07: 50)"}
    REPORT_PERIOD_S: ClassVar[float] = 2.0  #: each channel's sensor reports this often
    OFFLINE_WINDOW_S: ClassVar[float] = 300.0
    OFFLINE_PROBABILITY: ClassVar[float] = 0.04  #: per channel and window

    def __init__(self, address: int = _MAP.device.default_address, *, baud: int = 9600,
                 seed: int = 0, clock: SimClock | None = None, firmware: str = _LATEST,
                 response_delay: float | tuple[float, float] = 0.0,
                 humidity_tenths: bool = True, channels: Sequence[Channel] | None = None,
                 dynamic: bool = True) -> None:
        parse_firmware(firmware)  # "" too: a hub runs a version
        if channels is not None and len(channels) != _N:
            raise InvalidArgument(f"channels must list {_N} Channel entries, got {len(channels)}")
        super().__init__(_MAP, address, baud=baud, seed=seed, clock=clock, dynamic=dynamic,
                         firmware=firmware, delay=response_delay)
        self._channels = [replace(c) for c in channels] if channels is not None else [
            self._seeded_channel(ci, humidity_tenths) for ci in range(_N)]
        self._models = [self._seeded_model(ci) for ci in range(_N)]
        self._by_phase = sorted(range(_N), key=lambda ci: self._models[ci][1])
        self._phases = [self._models[ci][1] for ci in self._by_phase]
        self._episodes = [(-1, 0.0, 0.0)] * _N  # channel index -> (window, start, end)
        self._now()

    @classmethod
    def _from_spec(cls, target: MapTarget, args: dict[str, object], *, seed: int,
                   clock: SimClock | None) -> MapSimDevice:
        if "humidity_unit" in target.options:
            args["humidity_tenths"] = target.options["humidity_unit"] == 0.1
        return super()._from_spec(target, args, seed=seed, clock=clock)

    def _start(self, rng: random.Random) -> None:
        """The values come from the channel models (:meth:`_refresh`)."""

    # -- configuration -----------------------------------------------------------------

    def _channels_of(self, p: Point) -> int:
        n = super()._channels_of(p)
        return min(n, _LEGACY[1]) if parse_firmware(self._firmware) <= _LEGACY[0] else n

    def supports(self, name: str | None = None, *, block: str | None = None) -> bool:
        """True when the firmware has block (or point) ``name``; ``block=``
        is the keyword's earlier name, still taken."""
        if (name is None) == (block is None):
            raise InvalidArgument("supports() takes one block name")
        return super().supports(name if name is not None else block)  # type: ignore[arg-type]

    def channel(self, channel: int) -> Channel:
        """The configuration of ``channel`` (1-based); a copy."""
        return replace(self._channels[self._cis(channel)[0]])

    @_locked
    def configure(self, /, channel: int | Iterable[int] | None = None, **flags: bool) -> None:
        """Change what is plugged into ``channel`` (1-based, several, or
        None for all): ``present``, ``temperature``, ``humidity``,
        ``pressure``, ``temperature2``, ``humidity_tenths`` (see :class:`Channel`)."""
        names = {f.name for f in fields(Channel)}
        if set(flags) - names:
            raise InvalidArgument(f"unknown channel flags {sorted(set(flags) - names)}; "
                                  f"use {sorted(names)}")
        for ci in self._cis(channel):
            self._channels[ci] = replace(self._channels[ci],
                                         **{k: bool(v) for k, v in flags.items()})
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
        return bytes(c.humidity_tenths for c in self._channels)

    def _channel_changed(self, ci: int, t: float) -> None:
        self._update(ci, t)

    @_locked
    def sensor_fault(self, rng: random.Random, seconds: float, *, bits: int | None = None,
                     channels: Sequence[int] | None = None) -> str:
        """Take ``channels`` (default: one present channel) offline for ``seconds``."""
        if not channels:
            channels = [rng.choice([ci + 1 for ci in range(self.channels)
                                    if self._channels[ci].present] or [1])]
        self.set_offline(channels, True, seconds)
        return f"channels {', '.join(map(str, channels))} offline for {seconds:g} s"

    @_locked
    def idle(self) -> None:
        """Refresh the channels that reported since the last request."""
        self._now()

    def describe(self) -> str:
        """One line for the command line's banner."""
        present = sum(c.present for c in self._channels[:self.channels])
        blocks = sum(1 for p in _BLOCKS if self._channels_of(p))
        return (f"hub at address {self.address} ({self.baud} 8N1), firmware "
                f"{self.firmware} ({self.channels} channels, {blocks} blocks), {present} sensors")

    # -- the value model -------------------------------------------------------------------

    def _seeded_channel(self, ci: int, tenths: bool) -> Channel:
        u = _noise(self.seed, 100, ci)
        # 10 % unpaired, 45 % temperature and humidity, 20 % temperature only,
        # 10 % two probes, the rest a pressure sensor
        return Channel(present=u >= 0.10, humidity=u < 0.55,
                       temperature2=0.75 <= u < 0.85, temperature=u < 0.85,
                       pressure=u >= 0.85, humidity_tenths=tenths)

    def _seeded_model(self, ci: int) -> tuple[float, ...]:
        """Per-channel parameters, drawn once from the seed: the root of its
        noise, its report phase, temperature (tenths of a degree), its swing
        and period, humidity (0.1 %), pressure temperature, pressure (kPa),
        voltage (mV), RSSI (dBm), second temperature."""
        u = [_noise(self.seed, 200 + salt, ci) for salt in range(12)]
        temp = -180.0 - 70.0 * u[2] if u[1] < 0.25 else 150.0 + 150.0 * u[2]  # some freeze
        return (_mix(_mix(self.seed & _M64) ^ ci), self.REPORT_PERIOD_S * u[0], temp,
                5.0 + 25.0 * u[3], 600.0 + 3000.0 * u[4], 300.0 + 400.0 * u[5],
                180.0 + 120.0 * u[6], 95.0 + 10.0 * u[7] if u[8] < 0.5 else 200.0 + 400.0 * u[7],
                3000.0 + 600.0 * u[9], -45.0 - 50.0 * u[10], temp + 20.0 * (u[11] - 0.5))

    def _offline(self, ci: int, t: float) -> bool:
        held = self._held_offline(ci)
        if held is not None or not self.dynamic:
            return bool(held)
        w = int(t // self.OFFLINE_WINDOW_S)
        if self._episodes[ci][0] != w:  # one offline episode at most per window, drawn once
            start, end = episode(int(self._models[ci][0]), 300, w, self.OFFLINE_WINDOW_S,
                                 self.OFFLINE_PROBABILITY, 60.0) or (0.0, 0.0)
            self._episodes[ci] = (w, start, end)
        return self._episodes[ci][1] <= t < self._episodes[ci][2]

    def _update(self, ci: int, t: float) -> None:
        """Write the channel's registers, block by block, as of its last report before ``t``."""
        key, phase, temp, amp, period, hum, p_temp, kpa, volt, rssi, temp2 = self._models[ci]
        c = self._channels[ci]
        k = math.floor((t - phase) / self.REPORT_PERIOD_S)
        tk = phase + k * self.REPORT_PERIOD_S
        img = self._images["holding"]
        if not c.present or self._offline(ci, tk):
            for a in _ADDRESS:
                img[a + ci] = _OFFLINE
            return
        h = _mix(int(key) ^ (k & _M64))  # one hash per report: 8 bits of noise each below
        n = [(h >> shift & 0xFF) / 256.0 - 0.5 for shift in range(0, 56, 8)]
        wave = math.sin(_TWO_PI * tk / period + ci)
        humidity = min(1000.0, max(0.0, hum - 60.0 * wave + 8.0 * n[0]))
        raws = (sign_magnitude(round(temp + amp * wave + 3.0 * n[1])),
                round(humidity) if c.humidity_tenths else round(humidity / 10.0),
                sign_magnitude(round(p_temp + 0.5 * amp * wave + 2.0 * n[2])),
                max(0, round(kpa * (1.0 + 0.02 * wave) + n[3])),
                max(0, round(volt - 10.0 * tk / 86400.0 + 6.0 * n[4])),
                # RSSI stays at -2 dBm or below, so it never reads as 0xFFFF
                round(rssi + 6.0 * n[5]) & 0xFFFF,
                sign_magnitude(round(temp2 + amp * wave + 3.0 * n[6])))
        for a, raw, sensor in zip(_ADDRESS, raws, _SENSORS, strict=True):
            img[a + ci] = raw if getattr(c, sensor) else \
                _NO_HUMIDITY[c.humidity_tenths] if sensor == "humidity" else _OFFLINE

    def _refresh(self) -> None:
        """Bring the image to now: only the channels that reported since the
        last refresh are recomputed (each channel reports every
        REPORT_PERIOD_S at its own phase)."""
        t, last, period = self.clock.now(), self._updated, self.REPORT_PERIOD_S
        if last == t:
            return
        changed: Iterable[int] = range(_N)
        if last <= t < last + period:
            lo = bisect.bisect_right(self._phases, last % period)
            hi = bisect.bisect_right(self._phases, t % period)
            changed = (self._by_phase[lo:hi] if last % period <= t % period
                       else self._by_phase[lo:] + self._by_phase[:hi])
        for ci, until in list(self._offline_until.items()):
            if until <= t:
                del self._offline_until[ci]
                self._update(ci, t)
        for ci in changed:
            self._update(ci, t)
        self._updated = t
