"""Which devices stopped answering, from what the logger writes.

A Sparkplug edge node publishes a DDEATH for a device that "becomes
unavailable for any reason (no response, CRC error, etc.)" (Sparkplug 3.0,
tck-id-operational-behavior-device-ddeath) and a DBIRTH when it answers
again. pymb's logger records every
failed poll as a fault event (:data:`pymb.store.FAULT_KINDS`); a device is
*down* after :data:`DOWN_AFTER` faults in a row with no sample between them,
and up again with its next sample. A bus that cannot be (re)connected (a
``connection`` event with no device) counts as a fault of every device seen
on that bus.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from pymb.store.records import FAULT_KINDS

if TYPE_CHECKING:
    from pymb.store import StoredSample

__all__ = ["DOWN_AFTER", "DeviceHealth", "Down", "due_downs"]

DOWN_AFTER = 3  #: faults in a row (no sample between them) after which a device is down


@dataclass(frozen=True)
class Down:
    """A device went down."""

    device: str
    last_sample: float | None  #: time_utc of its last sample before, if this run had one
    time_utc: float  #: the fault that made it down


class DeviceHealth:
    """Counts each device's faults in a row; fed by the sink the logger writes to."""

    def __init__(self, down_after: int = DOWN_AFTER) -> None:
        self.fault_kinds = FAULT_KINDS
        self.down_after = down_after
        self.on_bus: dict[str, set[str]] = {}
        self.faults: dict[str, int] = {}
        self.last: dict[str, float] = {}
        self.down: set[str] = set()
        self._new: list[Down] = []

    def _seen(self, device: Any) -> str:
        self.on_bus.setdefault(device.bus, set()).add(device.name)
        return str(device.name)

    def sample(self, sample: Any) -> None:
        """A sample: its device answers."""
        name = self._seen(sample.device)
        self.faults[name] = 0
        self.last[name] = sample.time_utc
        self.down.discard(name)

    def event(self, event: Any) -> None:
        """An event: a fault of its device, or of every device of its bus."""
        if event.kind not in self.fault_kinds:
            return
        if event.device is not None:
            names = [self._seen(event.device)]
        elif event.kind == "connection":
            names = sorted(self.on_bus.get(event.bus, ()))
        else:
            return
        for name in names:
            n = self.faults[name] = self.faults.get(name, 0) + 1
            if n >= self.down_after and name not in self.down:
                self.down.add(name)
                self._new.append(Down(name, self.last.get(name), event.time_utc))

    def take(self) -> list[Down]:
        """The devices that went down since the last call, in order."""
        out, self._new = self._new, []
        return out


def due_downs(pending: list[tuple[Down, int]], rec: StoredSample | None, upto: int
              ) -> tuple[list[Down], list[tuple[Down, int]]]:
    """The downs of ``pending`` ((down, the highest sample id committed with
    it)) due now, and the rest: before ``rec``, those of its device that
    came after its previous sample; with no ``rec``, those committed up to
    ``upto``."""
    due: list[Down] = []
    keep = []
    for d, at in pending:
        if rec is None:
            ok = at <= upto
        else:
            ok = d.device == rec.device.name and (d.last_sample is None
                                                 or rec.time_utc > d.last_sample)
        if ok:
            due.append(d)
        else:
            keep.append((d, at))
    return due, keep
