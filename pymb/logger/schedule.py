"""The one schedule of ``pymb log``: pure rules, no I/O. A bus's thread
(:mod:`pymb.logger.poller`) and the one TCP loop (:mod:`pymb.logger.tcploop`)
both run it and do only the reading and the writing.

- :class:`Slot`: one thing read on a schedule (a group of a map device, or
  a CoolPro or hub read through its facade) on drift-free slots: slot k at
  start + k·interval; the whole slots a long read overran are skipped and
  counted, never crammed in.
  Interval 0 is flat out, or, for a map group (``once``), one read after the
  device (re)appears: not again on a connection the device itself closed
  after its replies.
- :class:`~pymb.devices.retry.Health`: a device's failures in a row and
  when it is tried again (a map device is offline for ``offline_retry`` after
  ``offline_after`` failed polls; a facade device backs off 0.5 s doubling to
  30 s after ten failures in a row), and
  :class:`~pymb.devices.retry.Backoff`, that doubling wait (a bus that does
  not open is tried again 0.5 s doubling to 30 s later): the rules of
  :mod:`pymb.devices.retry`, below the logger, which ``pymb watch`` keeps too.
- :class:`Agenda`: which slots are due when, for a whole bus or loop.
- The batching of samples for the writer (:data:`BATCH_MAX`, :data:`BATCH_AGE`)
  and the text of each event these rules give (:data:`TEXT`).
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Generic, TypeVar

from pymb.devices.retry import (
    BACKOFF,
    BACKOFF_FIRST,
    BACKOFF_MAX,
    FAULTS_BEFORE_BACKOFF,
    OFFLINE,
    Backoff,
    Health,
)

__all__ = ["BACKOFF_FIRST", "BACKOFF_MAX", "BATCH_AGE", "BATCH_MAX", "FAULTS_BEFORE_BACKOFF",
           "TEXT", "Agenda", "Backoff", "Health", "Slot", "reappeared"]

#: A poller hands its samples to the writer in lists of at most this many, or
#: this old (seconds), and before it waits: one queue operation per list, not
#: two per sample. Events go at once, after the samples before them.
BATCH_MAX = 64
BATCH_AGE = 0.02

#: The text of each event the pollers record, one per fact (``str.format``
#: fields); a failed poll's text is its error's, with "offline" or "backoff".
TEXT = {
    "connect": "polling {devices} device(s) on {endpoint}",
    "reconnect": "reconnected to {endpoint}",
    "retrying": "{why}; retrying in {wait:g} s",
    "lost": "{endpoint}: {why}{retry}",
    "closed": "{endpoint}: the connection was closed by the device after {replies}; "
              "opening it again",
    "closes": "{endpoint} closes the connection after {replies}: {n} request(s) per "
              "connection from now on",
    "stray": "{endpoint}: bytes no request asked for (received {got})",
    "no_value": "{name} supplied no value: {why}",
    "skipped": "{late} poll slot(s) of {interval:g} s skipped ({what})",
    "online": "{name} answers again",
    "offline": OFFLINE,
    "backoff": BACKOFF,
}


@dataclass(eq=False)
class Slot:
    """One thing read on a schedule: a map device's group, or a facade device."""

    health: Health
    interval: float  #: seconds; 0: flat out, or once (``once``)
    once: bool = False  #: a map group of interval 0: read once after the device (re)appears
    group: str | None = None
    next_at: float = 0.0
    read_once: bool = False  #: a ``once`` group read since the device (re)appeared

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
        return TEXT["skipped"].format(late=late, interval=self.interval, what=self.what)


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
