"""Steps of the wall clock, seen from the monotonic clock.

A board without a real-time clock boots in 1970 (or at the date its image
was built) and is stepped to the right time by NTP a minute later; an
operator may set the clock back. The offset ``time.time() -
time.monotonic()`` stays put while the clock runs (NTP's slewing moves it
by microseconds a second) and jumps at a step: :class:`ClockWatch` sees the
jump, and the logger records it as a ``clock`` event and re-stamps the
samples it took before it (see ``docs/board.md``).

A time before :data:`PLAUSIBLE` cannot be the real time: pymb did not exist
then. Samples stamped before it were taken while the clock was not set. A
clock that was set and steps to such a time (a lost real-time clock, a bad
step) is wrong, not the stamps: they are kept, and the samples that follow
are stamped from the monotonic clock and the last offset of the set clock,
until the clock is set again.
"""

from __future__ import annotations

import dataclasses
import time

from pymb.store import Event, Sample
from pymb.store.block import PollBlock
from pymb.store.retention import PLAUSIBLE, RESTAMP_TOLERANCE, clock_plausible

__all__ = ["PLAUSIBLE", "STEP", "ClockWatch", "clock_plausible", "offset", "restamped"]

STEP = RESTAMP_TOLERANCE  #: seconds: a change of the offset larger than this is a step


def offset() -> float:
    """``time.time() - time.monotonic()``: the wall time of monotonic 0."""
    return time.time() - time.monotonic()


class ClockWatch:
    """Notices steps of the wall clock (call :meth:`check` often)."""

    #: seconds a stamp may differ from monotonic + offset and still be of the same clock
    tolerance = STEP

    def __init__(self) -> None:
        self.offset = offset()  #: the offset the stamps use (wall minus monotonic)
        self._clock = self.offset  #: the offset the wall clock itself last gave
        self.steps = 0
        #: True while a clock that was set reads a time before PLAUSIBLE: the
        #: stamps keep the last offset of the set clock
        self.held = False

    def check(self) -> float | None:
        """The step (seconds, positive: forward) since the last call, or None."""
        now = offset()
        step = now - self._clock
        if abs(step) <= STEP:
            return None
        self._clock = now
        self.steps += 1
        mono = time.monotonic()
        # A set clock stepped into an earlier epoch: the clock is wrong, not the stamps.
        self.held = clock_plausible(mono + self.offset) and not clock_plausible(mono + now)
        if not self.held:
            self.offset = now
        return step

    def message(self, step: float, stored: bool) -> str:
        """The event's words for a step of ``step`` seconds (``stored``: what the run
        stored before it is re-stamped too, not only what it still holds)."""
        after = time.time()
        before = after - step

        def when(t: float) -> str:
            return time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime(t))

        way = "forward" if step > 0 else "back"
        if self.held:
            return (f"the clock stepped {way} by {abs(step):,.1f} s, from {when(before)} to "
                    f"{when(after)}, a time before {when(PLAUSIBLE)[:10]} that cannot be the "
                    "real one; what was stored keeps its time, and the samples are stamped "
                    "from the monotonic clock and the last time the clock was set")
        note = "" if clock_plausible(before) else " (the clock had not been set)"
        what = "this run's earlier samples and events are" if stored else \
            "the samples not yet written are"
        return (f"the clock stepped {way} by {abs(step):,.1f} s, from {when(before)} to "
                f"{when(after)}{note}; {what} re-stamped from the monotonic clock")


def restamped(items: list[Sample | Event | PollBlock], offset: float
              ) -> list[Sample | Event | PollBlock]:
    """``items`` with the wall time of those stamped before a clock step
    recomputed from their monotonic time and the clock's ``offset`` (the same
    list when none needs it; a block of polls by its first poll's times,
    which set every poll's)."""
    limit = ClockWatch.tolerance
    if all(abs(i.time_utc - i.monotonic - offset) <= limit for i in items):
        return items
    return [i if abs(i.time_utc - i.monotonic - offset) <= limit
            else dataclasses.replace(i, time_utc=i.monotonic + offset) for i in items]
