"""Report by exception: which readings ``--on-change`` stores."""

from __future__ import annotations

import math
from array import array
from dataclasses import dataclass, field

from pymb.devices import HUB, CoolProTelemetry, HubReading
from pymb.devices.mapreading import MapReading
from pymb.devices.readings import INTEGRAL_QUANTITIES
from pymb.errors import InvalidArgument
from pymb.store.schema import COOLPRO_FIELDS, HUB_FIELDS

__all__ = ["DEADBAND_QUANTITIES", "CoolProChanges", "HubChanges", "MapChanges", "OnChange"]

#: the built-in devices' quantities that take a deadband (OnChange.deadband)
DEADBAND_QUANTITIES = tuple(sorted(set(HUB_FIELDS) | set(COOLPRO_FIELDS) - INTEGRAL_QUANTITIES))


@dataclass
class OnChange:
    """Report by exception (``pymb log --on-change``).

    A hub channel is stored when one of its quantities moved more than its
    ``deadband`` (engineering units, by quantity name; 0 or absent: any change)
    since the channel was last stored, when a state changes (offline, no
    sensor, unsupported), and at least every ``heartbeat`` seconds. A
    CoolPro sample is stored on the same rules over its quantities (its
    uptime only when it restarts). The value at time t is then the last
    stored row at or before t (docs/storage.md).
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


class HubChanges:
    """Which channels of a hub sweep to store, against what was last stored."""

    def __init__(self, rules: OnChange, channels: int) -> None:
        self.rules = rules
        self.channels = channels
        self.bands = [rules.deadband.get(b.name, 0.0) for b in HUB.blocks]
        self.regs: array[int] | None = None  # the previous sweep's registers
        self.mask = -1
        self.values = array("d", bytes(8 * 7 * channels))  # last stored, per channel
        self.states = array("B", bytes(7 * channels))
        self.due = [0.0] * channels  # heartbeat deadline per channel (monotonic)
        self.next_due = 0.0

    def changed(self, data: HubReading, now: float) -> list[int]:
        """0-based channels to store now (and remembers them as stored)."""
        c = self.channels
        regs = data.registers
        if self.regs is None or data.unsupported_mask != self.mask:
            pick = set(range(c))
        else:
            pick = set()
            prev = self.regs
            n = HUB.channels
            for b in range(len(HUB.blocks)):
                lo = b * n
                if regs[lo:lo + c] == prev[lo:lo + c]:
                    continue  # nothing in this block moved since the last sweep
                band = self.bands[b]
                vals, sts = data.values, data.raw_states
                for ch in range(c):
                    if ch in pick or regs[lo + ch] == prev[lo + ch]:
                        continue
                    i = b * c + ch
                    if sts[i] != self.states[i] or (
                            sts[i] == 0 and abs(vals[i] - self.values[i]) > band):
                        pick.add(ch)
            if now >= self.next_due:
                pick.update(ch for ch in range(c) if now >= self.due[ch])
        self.regs = array("H", regs)
        self.mask = data.unsupported_mask
        if pick:
            vals, sts = data.values, data.raw_states
            for ch in pick:
                for b in range(len(HUB.blocks)):
                    i = b * c + ch
                    self.values[i] = vals[i]
                    self.states[i] = sts[i]
                self.due[ch] = now + self.rules.heartbeat
            self.next_due = min(self.due)
        return sorted(pick)


class CoolProChanges:
    _FIELDS = ("input_voltage_v", "input_current_a", "output_voltage_v", "output_current_a",
               "temperature_c")

    def __init__(self, rules: OnChange) -> None:
        self.rules = rules
        self.last: CoolProTelemetry | None = None
        self.due = 0.0

    def changed(self, data: CoolProTelemetry, now: float) -> bool:
        last = self.last
        store = (last is None or now >= self.due or data.status != last.status
                 or data.uptime_s < last.uptime_s
                 or any(abs(getattr(data, f) - getattr(last, f))
                        > self.rules.deadband.get(f, 0.0) for f in self._FIELDS))
        if store:
            self.last = data
            self.due = now + self.rules.heartbeat
        return store


class MapChanges:
    """Whether to store a map device's group reading: when a point moved more
    than its deadband (``bands`` by point name, else the point's ``deadband``
    in its map, else 0: any change; a block channel by channel), when a
    state or a value that is not a number changes, and at least every
    heartbeat."""

    def __init__(self, rules: OnChange, bands: dict[str, float]) -> None:
        self.rules = rules
        self.bands = bands
        self.last: MapReading | None = None
        self.due = 0.0

    def _moved(self, data: MapReading, last: MapReading) -> bool:
        if data.states != last.states:
            return True
        points = data.map.points
        for name, v in data.values.items():
            old = last.values.get(name)
            band = self.bands.get(name, points[name].deadband or 0.0)
            pairs = zip(v, old, strict=False) if isinstance(v, list) and isinstance(
                old, list) else ((v, old),)
            for a, b in pairs:
                if isinstance(a, (int, float)) and isinstance(b, (int, float)) and not \
                        isinstance(a, bool):
                    if abs(a - b) > band or (a != a) != (b != b):
                        return True
                elif a != b:
                    return True
        return False

    def changed(self, data: MapReading, now: float) -> bool:
        """Whether ``data`` is stored (and becomes what the next is compared with)."""
        last = self.last
        store = last is None or now >= self.due or self._moved(data, last)
        if store:
            self.last = data
            self.due = now + self.rules.heartbeat
        return store
