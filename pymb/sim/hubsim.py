"""The sensor hub's behaviours over its map (``hub``): the map sets the
registers, blocks, addresses and the firmware each block needs; this adds
the hub's one firmware rule the map cannot say (V1.07 and below: 50
channels of temperature and humidity only), what is plugged into each
channel (per-channel humidity units), and the values of each channel as a
deterministic function of seed and simulated time (a model per channel)."""

from __future__ import annotations

import bisect
import math
import random
from array import array
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, fields
from typing import ClassVar

from pymb import maps
from pymb.errors import InvalidArgument
from pymb.maps import Point
from pymb.sim.base import (
    _M64,
    _TWO_PI,
    ExceptionCode,
    _locked,
    _mix,
    _noise,
    parse_firmware,
    sign_magnitude,
)
from pymb.sim.clock import SimClock
from pymb.sim.mapsim import MapSimDevice

__all__ = ["Channel", "HubDevice"]

_MAP = maps.builtin("hub")
_BLOCKS = tuple(_MAP.points.values())
_NAMES = tuple(p.name for p in _BLOCKS)
_ADDRESS = tuple(p.address for p in _BLOCKS)  # each block's first register
_FIRST = min(_ADDRESS)
_COUNT = max(p.address + p.channels * p.stride for p in _BLOCKS) - _FIRST
_N = max(p.channels for p in _BLOCKS)
#: V1.07 and below: 50 channels of these blocks only
_LEGACY = ((1, 7), 50, ("temperature_c", "humidity_pct"))
_LATEST = max((p.min_firmware for p in _BLOCKS if p.min_firmware), key=parse_firmware)


def _marker(p: Point, state: str) -> int:
    return next(raw for raw, name in p.markers.items() if name == state)


_OFFLINE = _marker(_BLOCKS[0], "offline")
_ALL_OFFLINE = [_OFFLINE] * len(_BLOCKS)
_NO_HUMIDITY = {tenths: _marker(_MAP.configure(humidity_unit=0.1 if tenths else 1)
                                .points["humidity_pct"], "no_sensor") for tenths in (False, True)}


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


#: which Channel flag each block depends on
_SENSOR = {"temperature_c": "temperature", "humidity_pct": "humidity",
           "pressure_temperature_c": "pressure", "pressure_kpa": "pressure",
           "voltage_mv": "present", "rssi_dbm": "present", "temperature2_c": "temperature2"}
_BLOCK_SENSORS = tuple((name, _SENSOR[name]) for name in _NAMES)


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
    REPORT_PERIOD_S: ClassVar[float] = 2.0  #: each channel's sensor reports this often
    OFFLINE_WINDOW_S: ClassVar[float] = 300.0
    OFFLINE_PROBABILITY: ClassVar[float] = 0.04  #: per channel and window

    def __init__(
        self,
        address: int = _MAP.device.default_address,
        *,
        baud: int = 9600,
        seed: int = 0,
        clock: SimClock | None = None,
        firmware: str = _LATEST,
        response_delay: float | tuple[float, float] = 0.0,
        humidity_tenths: bool = True,
        channels: Sequence[Channel] | None = None,
        dynamic: bool = True,
    ) -> None:
        lo, hi = response_delay if isinstance(response_delay, tuple) else (response_delay,) * 2
        if not 0 <= lo <= hi:
            raise InvalidArgument(f"response_delay must be seconds >= 0 (or a low, high "
                                  f"range), got {response_delay!r}")
        parse_firmware(firmware)  # "" too: a hub runs a version
        if channels is not None and len(channels) != _N:
            raise InvalidArgument(f"channels must list {_N} Channel entries, got {len(channels)}")
        super().__init__(_MAP, address, baud=baud, seed=seed, clock=clock, dynamic=dynamic,
                         firmware=firmware)
        self.response_delay = response_delay
        self._image = self._images["holding"]
        self._channels = list(channels) if channels is not None else [
            self._seeded_channel(ci, humidity_tenths) for ci in range(_N)]
        self._models = [self._seeded_model(ci) for ci in range(_N)]
        order = sorted(range(_N), key=lambda ci: self._models[ci].phase)
        self._by_phase = order
        self._phases = [self._models[ci].phase for ci in order]
        self._pins: dict[tuple[int, int], int] = {}  # (block index, channel index) -> raw
        self._forced: dict[int, bool] = {}  # channel index -> offline (True) / online
        self._offline_until: dict[int, float] = {}  # channel index -> simulated expiry
        self._episodes = [(-1, 0.0, 0.0)] * _N  # channel index -> (window, start, end)
        self._refreshed: float | None = None
        self._refresh()

    def _start(self, rng: random.Random) -> None:
        """The values come from the channel models (:meth:`_refresh`)."""

    # -- configuration -----------------------------------------------------------------

    def _channels_of(self, p: Point) -> int:
        if self._firmware and parse_firmware(self._firmware) <= _LEGACY[0]:
            return _LEGACY[1] if p.name in _LEGACY[2] else 0
        return super()._channels_of(p)

    @property
    def channels(self) -> int:
        """Channels the firmware serves (50 on V1.07 and below, else 100)."""
        return max(self._channels_of(p) for p in _BLOCKS)

    def supports(self, block: str) -> bool:
        """True when the firmware has ``block`` (a block's name)."""
        return block in _NAMES and self._channels_of(_MAP.points[block]) > 0

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
        ci = self._ci(channel)
        self._pins[(self._block(block), ci)] = raw & 0xFFFF
        self._update(ci, self.clock.now())

    @_locked
    def unpin(self, block: str | None = None, channel: int | None = None) -> None:
        """Drop pins (all, one block's, or one register's)."""
        for key in list(self._pins):
            if (block is None or key[0] == self._block(block)) and (
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
    def registers(self, address: int = _FIRST, count: int = _COUNT) -> array[int]:
        """The register image now (whatever the firmware lacks included)."""
        self._refresh()
        return self._image[address:address + count]

    @_locked
    def sensor_fault(self, rng: random.Random, seconds: float, *, bits: int | None = None,
                     channels: Sequence[int] | None = None) -> str:
        """Take ``channels`` (default: one present channel) offline for ``seconds``."""
        if not channels:
            present = [ci + 1 for ci in range(self.channels)
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

    def describe(self) -> str:
        """One line for the command line's banner."""
        n = self.channels
        present = sum(1 for c in self._channels[:n] if c.present)
        blocks = sum(1 for p in _BLOCKS if self._channels_of(p))
        return (f"hub at address {self.address} ({self.baud} 8N1), firmware "
                f"{self.firmware} ({n} channels, {blocks} blocks), {present} sensors")

    # -- the value model -------------------------------------------------------------------

    @staticmethod
    def _ci(channel: int) -> int:
        if not 1 <= channel <= _N:
            raise InvalidArgument(f"channel must be 1..{_N}, got {channel!r}")
        return channel - 1

    def _cis(self, channel: int | Iterable[int] | None) -> list[int]:
        if channel is None:
            return list(range(_N))
        if isinstance(channel, int):
            return [self._ci(channel)]
        return [self._ci(c) for c in channel]

    @staticmethod
    def _block(name: str) -> int:
        if name not in _NAMES:
            raise InvalidArgument(f"no block {name!r}; the hub's blocks: {', '.join(_NAMES)}")
        return _NAMES.index(name)

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
        img, offs = self._image, _ADDRESS
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
            changed: Iterable[int] = range(_N)
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
