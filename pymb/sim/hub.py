"""The simulated sensor hub: 100 channels of seven blocks, firmware profiles,
per-channel humidity units, and the values of each channel as a deterministic
function of seed and simulated time (a model per channel)."""

from __future__ import annotations

import bisect
import math
import random
from array import array
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, fields
from typing import ClassVar

from pymb.devices.maps import (
    HUB,
    HUB_FIRMWARE_PROFILES,
    Block,
)
from pymb.errors import (
    InvalidArgument,
)
from pymb.sim.base import (
    _M64,
    _TWO_PI,
    Device,
    ExceptionCode,
    _locked,
    _mix,
    _noise,
    _swapped,
    exception_pdu,
    parse_firmware,
    sign_magnitude,
)
from pymb.sim.clock import SimClock

__all__ = ["Channel", "HubDevice"]


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
        return HUB.block(name)  # an unknown name is an InvalidArgument naming the blocks

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
