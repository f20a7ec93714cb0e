"""When a device is read, and tried again after a failure: the rules of the
one schedule, pure, no I/O, written once for every poller (``pymb log``'s
bus threads and its TCP loop through :mod:`pymb.logger.schedule`, ``pymb
watch``, the bench's bare loop :mod:`pymb.bench.fanout`), which do only the
reading.

- :class:`Slot`: one thing read on a schedule (a group of a map device, or
  a device read whole) on drift-free slots: slot k at start + k·interval;
  the whole slots a long read overran are skipped and counted, never
  crammed in. Interval 0 is flat out, or, for a map group (``once``), one
  read after the device (re)appears (:func:`reappeared`): not again on a
  connection the device itself closed after its replies.
- :class:`Agenda`: which slots are due when, for a whole bus or loop.
- :class:`Backoff`: a doubling wait, :data:`BACKOFF_FIRST` s doubling to
  :data:`BACKOFF_MAX` s (a bus that does not open, a device backed off).
- :class:`Health`: a device's failed polls in a row and when it is tried
  again: a map device is offline for ``offline_retry`` s after
  ``offline_after`` failed polls, or, for a map of ``backoff = true``
  (CoolPro, hub), backed off with a doubling wait (:class:`Backoff`), at once
  after a poll that supplied no value.
- The texts of the events these rules give (:data:`SKIPPED`; what a
  failure's event adds: :data:`OFFLINE`, :data:`BACKOFF`).
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Generic, TypeVar

__all__ = ["BACKOFF", "BACKOFF_FIRST", "BACKOFF_MAX", "OFFLINE",
           "SKIPPED", "Agenda", "Backoff", "Health", "Slot", "reappeared"]

#: a doubling backoff's first and longest wait (seconds)
BACKOFF_FIRST, BACKOFF_MAX = 0.5, 30.0

#: what a failed poll's text adds when the device goes offline (``str.format`` fields)
OFFLINE = "; offline after {failures} failed poll(s), next try in {wait:g} s"
#: what a failed poll's text adds when the device is backed off
BACKOFF = "; next try in {wait:g} s"
#: the event of whole slots a long read overran
SKIPPED = "{late} poll slot(s) of {interval:g} s skipped ({what})"


class Backoff:
    """A doubling wait: :data:`BACKOFF_FIRST`, twice that, ... at most
    ``most`` seconds (:data:`BACKOFF_MAX`)."""

    __slots__ = ("most", "wait")

    def __init__(self, most: float = BACKOFF_MAX) -> None:
        self.most = most
        self.wait = min(BACKOFF_FIRST, most)  #: seconds of the next wait

    def take(self) -> float:
        """The wait now; the next one is twice as long."""
        wait = self.wait
        self.wait = min(wait * 2, self.most)
        return wait

    def reset(self) -> None:
        """Back to the first wait (the bus opened, or carried a reply)."""
        self.wait = min(BACKOFF_FIRST, self.most)


@dataclass(eq=False)
class Health:
    """How a device's polls go: failures in a row, and not polled before
    :attr:`retry_at` once they are too many."""

    name: str
    #: failed polls in a row before the device is left alone
    after: int
    #: seconds the device is offline; None: a doubling backoff (``backoff = true``)
    retry: float | None
    failures: int = 0  #: failed polls in a row
    retry_at: float = 0.0  #: not polled before this (clock)
    offline: bool = False  #: left alone for ``retry`` s (an ``online`` event when it answers)
    backoff: float = 0.0  #: the current doubling backoff (0: none)
    _waits: Backoff = field(default_factory=Backoff, init=False, repr=False)

    @classmethod
    def of_map(cls, name: str, offline_after: int | None,
               offline_retry: float | None, backoff: bool = False) -> Health:
        """A map device's: offline after ``offline_after`` failed polls (1 if
        unset) for ``offline_retry`` seconds (30 if unset), or with
        ``backoff`` (its map's ``[device.timing] backoff``) backed off then
        with a wait doubling up to ``offline_retry``."""
        retry = float(offline_retry or BACKOFF_MAX)
        if not backoff:
            return cls(name, offline_after or 1, retry)
        h = cls(name, offline_after or 1, None)
        h._waits = Backoff(retry)
        return h

    def failed(self, now: float, at_once: bool = False) -> str:
        """Count a failed poll at ``now`` (``at_once``: left alone now, however
        few the failures). Returns what the fault's event adds: when the
        next try is, if that is news."""
        self.failures += 1
        if not at_once and self.failures < self.after:
            return ""
        if self.retry is None:
            self.backoff = self._waits.take()
            self.retry_at = now + self.backoff
            return BACKOFF.format(wait=self.backoff)
        self.retry_at = now + self.retry
        if self.offline:
            return ""
        self.offline = True
        return OFFLINE.format(failures=self.failures, wait=self.retry)

    def answered(self) -> bool:
        """A poll succeeded; whether the device was offline (it is back)."""
        was = self.offline
        self.failures, self.offline, self.backoff = 0, False, 0.0
        self._waits.reset()
        return was


@dataclass(eq=False)
class Slot:
    """One thing read on a schedule: a device's group, or a device read whole."""

    health: Health
    interval: float  #: seconds; 0: flat out, or once (``once``)
    once: bool = False  #: a map group of interval 0: read once after the device (re)appears
    group: str | None = None
    next_at: float = 0.0
    read_once: bool = False  #: a ``once`` group read since the device (re)appeared

    @classmethod
    def every(cls, interval: float) -> Slot:
        """A slot alone, for a runner that retries a failed device its own way
        (its :class:`Health` is never told of a failure)."""
        return cls(Health("", 1, None), interval)

    @property
    def what(self) -> str:
        """The slot as events name it: ``NAME`` or ``NAME group GROUP``."""
        name = self.health.name
        return f"{name} group {self.group}" if self.group else name

    def due(self, now: float) -> bool:
        """Whether this slot is to be read at ``now``."""
        if now < self.health.retry_at:
            return False
        if self.once:
            return not self.read_once
        return self.interval == 0 or now >= self.next_at

    def wake(self, now: float) -> float:
        """When this slot is due next (inf: not before the device reappears)."""
        if self.once and self.read_once:
            return math.inf
        at = self.next_at if self.interval else now
        retry = self.health.retry_at
        return retry if retry > at else at

    def advance(self, now: float) -> int:
        """The slot was read (or failed), ending at ``now``: its next time.
        Returns how many whole slots the read overran (skipped)."""
        if self.once:
            self.read_once = True
            return 0
        interval = self.interval
        if interval == 0:
            return 0
        self.next_at += interval
        if now <= self.next_at:
            return 0
        late = int((now - self.next_at) / interval) + 1
        self.next_at += late * interval
        return late

    def skipped(self, late: int) -> str:
        """The ``skipped`` event's text for ``late`` slots skipped."""
        return SKIPPED.format(late=late, interval=self.interval, what=self.what)


def reappeared(slots: Iterable[Slot]) -> None:
    """The device(s) of ``slots`` may be new (a connection opened again after
    a failure): their ``once`` groups are read again."""
    for s in slots:
        s.read_once = False


T = TypeVar("T")


class Agenda(Generic[T]):
    """What is read next: items (each with its :class:`Slot`) by the time
    their slot falls due. A runner puts an item back after its read
    (:meth:`put` at :meth:`Slot.wake`) and takes the due ones (:meth:`due`)."""

    __slots__ = ("_heap", "_seq")

    def __init__(self) -> None:
        self._heap: list[tuple[float, int, Slot, T]] = []
        self._seq = 0  #: the order of puts, among items due at the same time

    def put(self, slot: Slot, item: T, when: float) -> None:
        """``item`` (read on ``slot``) falls due at ``when`` (never: inf)."""
        if when != math.inf:
            self._seq += 1
            heapq.heappush(self._heap, (when, self._seq, slot, item))

    def next(self) -> float:
        """When the first item falls due (inf: none will)."""
        heap = self._heap
        return heap[0][0] if heap else math.inf

    def due(self, now: float) -> list[T]:
        """The items whose slot is due at ``now``, in the order they fell
        due; one whose time came but not its slot's (its device is offline
        since) is put back at its slot's wake."""
        heap, out = self._heap, []
        while heap and heap[0][0] <= now:
            _, _, slot, item = heapq.heappop(heap)
            if slot.due(now):
                out.append(item)
            else:  # (its wake is after now: the loop ends)
                self.put(slot, item, slot.wake(now))
        return out
