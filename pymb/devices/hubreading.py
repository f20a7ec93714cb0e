"""One read of the sensor hub (:class:`HubReading`, a channel of it
:class:`HubChannel`): seven quantities of every channel in one float64
array and their states in one uint8 array, which numpy takes without a
copy. :mod:`pymb.devices.hub` reads them."""

from __future__ import annotations

import functools
import math
from array import array
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from pymb import _native, maps
from pymb.errors import InvalidArgument
from pymb.maps import Point

__all__ = ["ALL_BLOCKS", "BLOCKS", "CHANNELS", "HUB_FIRMWARE_PROFILES", "HUB_REGISTERS",
           "HubChannel", "HubReading", "State", "block_index", "check_channels",
           "humidity_in_other_unit"]

_MAP = maps.builtin("hub")
#: The hub's blocks in the order a reading keeps them: its map's points
#: (each one register a channel, channel 1's first), in address order.
BLOCKS: tuple[Point, ...] = tuple(_MAP.points.values())
#: The most channels a hub has (its map's ``channels`` option's default).
CHANNELS = int(_MAP.options["channels"])
HUB_REGISTERS = CHANNELS * len(BLOCKS)  # 700 registers, 31..730
#: The block mask with every block set (``HubReading.unsupported_mask ==
#: ALL_BLOCKS``: the hub supplied no value at all).
ALL_BLOCKS = (1 << len(BLOCKS)) - 1
_INDEX = {b.name: i for i, b in enumerate(BLOCKS)}
#: Firmware profiles of [HUB] / [NOTES]: (version, channels, blocks present).
#: V1.07 and below: 50 channels of temperature and humidity only.
HUB_FIRMWARE_PROFILES: dict[str, tuple[int, tuple[str, ...]]] = {
    "1.07": (50, ("temperature_c", "humidity_pct")),
    "2.18": (100, ("temperature_c", "humidity_pct", "pressure_temperature_c",
                   "pressure_kpa")),
    "2.22": (100, ("temperature_c", "humidity_pct", "pressure_temperature_c",
                   "pressure_kpa", "voltage_mv", "rssi_dbm")),
    "2.23": (100, tuple(b.name for b in BLOCKS)),
}
_ZERO_REGS = array("H", bytes(2 * HUB_REGISTERS))


#: Why a decoded value is (or is not) there: the C core's ``pymb_state``.
State = _native.State


@functools.lru_cache(maxsize=128)
def _zeros(channels: int) -> tuple[array[float], array[int]]:
    return array("d", bytes(8 * 7 * channels)), array("B", bytes(7 * channels))


def block_index(name: str) -> int:
    """Where block ``name`` sits in a reading (0..6); an unknown name is an
    InvalidArgument naming the blocks."""
    try:
        return _INDEX[name]
    except (KeyError, TypeError):
        raise InvalidArgument(f"unknown block {name!r}; use one of {', '.join(_INDEX)}") from None


def check_channels(channels: int) -> int:
    """``channels`` when it is a hub's channel count (1..100), else an InvalidArgument."""
    if isinstance(channels, bool) or not isinstance(channels, int) or not (
        1 <= channels <= CHANNELS
    ):
        raise InvalidArgument(f"channels must be 1..{CHANNELS}, got {channels!r}")
    return channels


_HUMIDITY = BLOCKS[block_index("humidity_pct")].address - BLOCKS[0].address
_DECODED = (State.VALUE, State.NO_SENSOR)


def humidity_in_other_unit(registers: Sequence[int], values: Any, states: Any, at: int,
                           unit: float, other: bytes) -> None:
    """The one rule for a channel whose humidity unit is not ``unit`` (1 in
    ``other``): its humidity (``values``/``states`` from ``at`` on, channel
    by channel) decoded again from the sweep's raw registers 31...
    ([HUB] 3, [NOTES]: 0x00FF is no humidity in the 1 % unit, 0x8000 in
    the 0.1 % unit)."""
    for i, flag in enumerate(other):
        if not flag or states[at + i] not in _DECODED:
            continue
        raw = registers[_HUMIDITY + i]
        if raw == 0xFFFF:
            continue  # offline in either unit
        if raw == (0x8000 if unit == 1.0 else 0x00FF):
            values[at + i], states[at + i] = math.nan, State.NO_SENSOR
        else:
            values[at + i] = raw / 10 if unit == 1.0 else float(raw)
            states[at + i] = State.VALUE


@dataclass(frozen=True)
class HubChannel:
    """One channel's values (NaN where there is none) and their states."""

    channel: int
    temperature_c: float
    humidity_pct: float
    pressure_temperature_c: float
    pressure_kpa: float
    voltage_mv: float
    rssi_dbm: float
    temperature2_c: float
    states: dict[str, State]


class HubReading:
    """One read of the hub: seven float sequences of ``channels`` values
    (``temperature_c``, ``humidity_pct``, ``pressure_temperature_c``,
    ``pressure_kpa``, ``voltage_mv``, ``rssi_dbm``, ``temperature2_c``), NaN
    where there is no value, and why in :meth:`states` /:meth:`state`.

    ``registers`` keeps the raw registers 31..730 (lossless); ``values`` and
    ``raw_states`` are the whole block-major arrays. ``time`` (UTC, seconds)
    and ``monotonic`` say when the read finished.
    """

    __slots__ = ("channels", "monotonic", "raw_states", "registers", "time",
                 "unsupported_mask", "values")

    def __init__(self, channels: int, registers: array[int] | None = None) -> None:
        if channels != CHANNELS:
            check_channels(channels)
        values, states = _zeros(channels)
        self.channels = channels
        self.registers = array("H", _ZERO_REGS) if registers is None else registers
        self.values = array("d", values)
        self.raw_states = array("B", states)
        self.unsupported_mask = 0
        self.time = 0.0
        self.monotonic = 0.0

    def _block(self, index: int) -> memoryview:
        c = self.channels
        return memoryview(self.values)[index * c:(index + 1) * c]

    @property
    def temperature_c(self) -> memoryview:
        """Channel temperatures, °C."""
        return self._block(0)

    @property
    def humidity_pct(self) -> memoryview:
        """Channel humidity, %."""
        return self._block(1)

    @property
    def pressure_temperature_c(self) -> memoryview:
        """Pressure sensors' temperatures, °C."""
        return self._block(2)

    @property
    def pressure_kpa(self) -> memoryview:
        """Pressures, kPa."""
        return self._block(3)

    @property
    def voltage_mv(self) -> memoryview:
        """Channel voltages, mV (firmware V2.19 and above)."""
        return self._block(4)

    @property
    def rssi_dbm(self) -> memoryview:
        """Channel RSSI, dBm (firmware V2.19 and above)."""
        return self._block(5)

    @property
    def temperature2_c(self) -> memoryview:
        """Second temperatures, °C (firmware V2.23 and above)."""
        return self._block(6)

    def states(self, name: str) -> memoryview:
        """The :class:`State` codes (uint8) of one quantity, per channel."""
        i = block_index(name)
        c = self.channels
        return memoryview(self.raw_states)[i * c:(i + 1) * c]

    def state(self, name: str, channel: int) -> State:
        """The :class:`State` of one quantity of one channel (1-based)."""
        self._check(channel)
        return State(self.raw_states[block_index(name) * self.channels + channel - 1])

    @property
    def unsupported(self) -> frozenset[str]:
        """Blocks this hub's firmware does not have."""
        return frozenset(b.name for i, b in enumerate(BLOCKS) if self.unsupported_mask >> i & 1)

    def _check(self, channel: int) -> None:
        if isinstance(channel, bool) or not isinstance(channel, int) or not (
            1 <= channel <= self.channels
        ):
            raise InvalidArgument(f"channel must be 1..{self.channels}, got {channel!r}")

    def channel(self, n: int) -> HubChannel:
        """Channel ``n`` (1-based): its seven values and their states."""
        self._check(n)
        c, i = self.channels, n - 1
        v = self.values
        states = {b.name: State(self.raw_states[k * c + i]) for k, b in enumerate(BLOCKS)}
        return HubChannel(n, v[i], v[c + i], v[2 * c + i], v[3 * c + i], v[4 * c + i],
                          v[5 * c + i], v[6 * c + i], states)

    def as_dict(self) -> dict[str, list[float | None]]:
        """Plain lists per quantity, None where there is no value (for JSON)."""
        return {
            b.name: [None if math.isnan(v) else v for v in self._block(i)]
            for i, b in enumerate(BLOCKS)
        }

    def __repr__(self) -> str:
        return f"<HubReading {self.channels} channels, unsupported={sorted(self.unsupported)}>"
