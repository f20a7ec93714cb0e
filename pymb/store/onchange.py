"""Report by exception: which readings ``--on-change`` stores, by one rule
over the points of the device's map."""

from __future__ import annotations

import copy
import math
from array import array
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from pymb import maps
from pymb.devices.mapreading import MapReading
from pymb.errors import InvalidArgument
from pymb.maps import Map, Value
from pymb.store.records import DeviceInfo

__all__ = ["DEADBAND_QUANTITIES", "Changes", "OnChange"]

_HUB, _COOLPRO = maps.builtin("hub"), maps.builtin("coolpro")
#: the built-in devices' quantities that take a deadband (OnChange.deadband):
#: the gauges of the hub's sweep and of the CoolPro's telemetry
DEADBAND_QUANTITIES = tuple(sorted({
    p.name for m, group in ((_HUB, "sweep"), (_COOLPRO, "telemetry"))
    for p in m.points.values() if p.group == group and p.kind == "gauge"}))


@dataclass
class OnChange:
    """Report by exception (``pymb log --on-change``).

    A reading is stored when one of its values moved more than its
    ``deadband`` (engineering units, by quantity name; 0 or absent: any
    change) since it was last stored, when a state changes (offline, no
    sensor, unsupported), and at least every ``heartbeat`` seconds; a hub
    channel by channel. The value at time t is then the last stored row at
    or before t (docs/storage.md).
    """

    heartbeat: float = 60.0
    deadband: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not (self.heartbeat > 0 and math.isfinite(self.heartbeat)):
            raise InvalidArgument(f"the heartbeat must be a positive number of seconds, "
                                  f"got {self.heartbeat!r}")
        for name, value in self.deadband.items():
            if name not in DEADBAND_QUANTITIES:
                raise InvalidArgument(f"no quantity {name!r} for a deadband; use one of "
                                      f"{', '.join(DEADBAND_QUANTITIES)}")
            if not (value >= 0 and math.isfinite(value)):
                raise InvalidArgument(f"deadband of {name} must be >= 0, got {value!r}")


#: a reading's values, value by value (a reading of blocks: the decoder's array)
_Values = Sequence[Value]
#: their states: names, or the decoder's state codes; only compared
_States = Sequence[object]


def _points(data: MapReading) -> tuple[Map, list[tuple[str, int]], _Values, _States]:
    """A reading as its map's points: the map, (name, values) of each point
    read (a block's channel by channel), and every value and state in that
    order (a reading of blocks: the decoder's arrays, NaN and state codes)."""
    b = data.blocks
    if b is not None and list(b.index.values()) == [i * b.channels for i in range(len(b.names))]:
        return data.map, [(n, b.channels) for n in b.names], b.values, b.states
    shape: list[tuple[str, int]] = []
    values: list[Value] = []
    states: list[object] = []
    for name, v in data.values.items():
        st = data.states.get(name)
        if isinstance(v, list) and isinstance(st, list):
            shape.append((name, len(v)))
            values += v
            states += st
        else:
            shape.append((name, 1))
            values.append(v)
            states.append(st)
    return data.map, shape, values, states


class Changes:
    """Which of a device's readings (``by_channel``: which channels of a
    hub's sweep) to store, against what was last stored: a value is stored
    when its state changed, when it moved more than its deadband (by point
    name: ``bands``, else the point's ``deadband`` in the map, else 0: any
    change), when a counter went back (a restart), and at least every
    heartbeat."""

    def __init__(self, rules: OnChange, bands: Mapping[str, float], by_channel: bool) -> None:
        self.rules = rules
        self.bands = bands
        self.by_channel = by_channel
        self.shape: list[tuple[str, int]] = []
        self.limits: list[tuple[int, int, float, bool]] = []  # lo, hi, band, counter
        self.prev: _Values = ()  # the previous reading's values, its bytes and states
        self.prev_key: tuple[bytes | _Values, bytes | _States] = (b"", b"")
        self.first = True
        self.values: list[Value] = []  # what was last stored, value by value
        self.states: list[object] = []
        self.due: list[float] = []  # heartbeat deadline per column (monotonic)
        self.next_due = 0.0

    @classmethod
    def of(cls, rules: OnChange, device: DeviceInfo, channels: int) -> Changes:
        """The rules of ``device`` (its map's deadbands over ``rules``'),
        by channel when it stores ``channels`` (not 0)."""
        return cls(rules, {**rules.deadband, **dict(device.map_deadband)}, by_channel=channels > 0)

    def _reset(self, m: Map, shape: list[tuple[str, int]]) -> None:
        self.shape = shape
        self.limits = []
        self.flat: list[tuple[float, bool]] = []  # band and counter, value by value
        lo = 0
        for name, n in shape:
            p = m.points.get(name)
            band = self.bands.get(name, (p.deadband if p is not None else None) or 0.0)
            counter = p is not None and p.kind == "counter"
            self.limits.append((lo, lo + n, band, counter))
            self.flat += [(band, counter)] * n
            lo += n
        self.first = True
        self.due = [0.0] * (shape[0][1] if self.by_channel and shape else 1)

    def changed(self, data: MapReading, now: float) -> list[int]:
        """The columns to store now (a hub's 0-based channels; ``[0]``: the
        whole reading), remembered as stored."""
        m, shape, vals, sts = _points(data)
        if shape != self.shape:
            self._reset(m, shape)
        # what did not move since the previous reading is skipped (as bytes: NaN is
        # NaN); a copy of a reading's arrays, which the next may be read into
        key = (vals.tobytes(), sts.tobytes()) if isinstance(vals, array) and \
            isinstance(sts, array) else (vals, sts)
        columns = len(self.due)
        if self.first:
            pick = set(range(columns))
            self.first = False
        elif self.by_channel:
            pick = self._moved(vals, sts, key)
        else:
            pick = self._moved_whole(vals, sts)
        if now >= self.next_due:
            pick.update(c for c in range(columns) if now >= self.due[c])
        self.prev, self.prev_key = copy.copy(vals), key
        if not pick:
            return []
        if not self.by_channel or len(pick) == columns:
            self.values, self.states = list(vals), list(sts)
        else:
            for lo, _, _, _ in self.limits:
                for c in pick:
                    self.values[lo + c] = vals[lo + c]
                    self.states[lo + c] = sts[lo + c]
        heartbeat = now + self.rules.heartbeat
        for c in pick:
            self.due[c] = heartbeat
        self.next_due = min(self.due)
        return sorted(pick)

    def _moved_whole(self, vals: _Values, sts: _States) -> set[int]:
        """{0} when a value of the reading is to be stored, else nothing."""
        for a, pa, s, ps, b, sb, (band, counter) in zip(
                vals, self.prev, sts, self.prev_key[1], self.values, self.states, self.flat,
                strict=True):
            if a == pa and s == ps:
                continue
            if s != sb:
                return {0}
            if (type(a) is float or type(a) is int) and (type(b) is float or type(b) is int):
                if abs(a - b) > band or (a != a) != (b != b) or (counter and a < b):
                    return {0}
            elif a != b:
                return {0}
        return set()

    def _moved(self, vals: _Values, sts: _States,
               key: tuple[bytes | _Values, bytes | _States]) -> set[int]:
        pick: set[int] = set()
        prev = self.prev
        (now_v, now_s), (old_v, old_s) = key, self.prev_key
        by_channel = self.by_channel
        size = 8 if isinstance(now_v, bytes) else 1
        for lo, hi, band, counter in self.limits:
            if now_v[lo * size:hi * size] == old_v[lo * size:hi * size] and \
                    now_s[lo:hi] == old_s[lo:hi]:
                continue  # nothing of this point moved since the previous reading
            for j, (a, pa, s, ps) in enumerate(zip(vals[lo:hi], prev[lo:hi], now_s[lo:hi],
                                                   old_s[lo:hi], strict=True)):
                c = j if by_channel else 0
                if (a == pa and s == ps) or c in pick:
                    continue
                b = self.values[lo + j]
                if s != self.states[lo + j]:
                    pick.add(c)
                elif (type(a) is float or type(a) is int) and (
                        type(b) is float or type(b) is int):
                    if abs(a - b) > band or (a != a) != (b != b) or (counter and a < b):
                        pick.add(c)
                elif a != b:
                    pick.add(c)
            if pick and not by_channel:
                break
        return pick
