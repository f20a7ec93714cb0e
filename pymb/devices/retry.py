"""When a device, or a line, that failed is tried again: pure rules, no I/O,
written once for every poller (``pymb log``'s schedule,
:mod:`pymb.logger.schedule`, and ``pymb watch``).

- :class:`Backoff`: a doubling wait, :data:`BACKOFF_FIRST` s doubling to
  :data:`BACKOFF_MAX` s (a bus that does not open, a device backed off).
- :class:`Health`: a device's failed polls in a row and when it is tried
  again: a map device is offline for ``offline_retry`` s after
  ``offline_after`` failed polls; a facade device (CoolPro, hub) is backed off
  after :data:`FAULTS_BEFORE_BACKOFF` failures in a row, or at once after one
  that supplied no value.
- The texts a failure's event adds (:data:`OFFLINE`, :data:`BACKOFF`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["BACKOFF", "BACKOFF_FIRST", "BACKOFF_MAX", "FAULTS_BEFORE_BACKOFF", "OFFLINE",
           "Backoff", "Health"]

#: a doubling backoff's first and longest wait (seconds)
BACKOFF_FIRST, BACKOFF_MAX = 0.5, 30.0
#: failed reads of a facade device (CoolPro, hub) in a row before it is backed off
FAULTS_BEFORE_BACKOFF = 10

#: what a failed poll's text adds when the device goes offline (``str.format`` fields)
OFFLINE = "; offline after {failures} failed poll(s), next try in {wait:g} s"
#: what a failed poll's text adds when the device is backed off
BACKOFF = "; next try in {wait:g} s"


class Backoff:
    """A doubling wait: :data:`BACKOFF_FIRST`, twice that, ... at most :data:`BACKOFF_MAX`."""

    __slots__ = ("wait",)

    def __init__(self) -> None:
        self.wait = BACKOFF_FIRST  #: seconds of the next wait

    def take(self) -> float:
        """The wait now; the next one is twice as long."""
        wait = self.wait
        self.wait = min(wait * 2, BACKOFF_MAX)
        return wait

    def reset(self) -> None:
        """Back to the first wait (the bus opened, or carried a reply)."""
        self.wait = BACKOFF_FIRST


@dataclass(eq=False)
class Health:
    """How a device's polls go: failures in a row, and not polled before
    :attr:`retry_at` once they are too many."""

    name: str
    #: failed polls in a row before the device is left alone
    after: int
    #: seconds a map device is offline; None: a facade device's doubling backoff
    retry: float | None
    failures: int = 0  #: failed polls in a row
    retry_at: float = 0.0  #: not polled before this (clock)
    offline: bool = False  #: a map device left alone (an ``online`` event when it answers)
    backoff: float = 0.0  #: a facade device's current backoff (0: none)
    _waits: Backoff = field(default_factory=Backoff, init=False, repr=False)

    @classmethod
    def of_map(cls, name: str, offline_after: int | None,
               offline_retry: float | None) -> Health:
        """A map device's: offline after ``offline_after`` failed polls (1 if
        unset) for ``offline_retry`` seconds (30 if unset)."""
        return cls(name, offline_after or 1, float(offline_retry or 30.0))

    @classmethod
    def of_facade(cls, name: str) -> Health:
        """A facade device's (CoolPro, hub): backed off after :data:`FAULTS_BEFORE_BACKOFF`."""
        return cls(name, FAULTS_BEFORE_BACKOFF, None)

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
