"""Simulated time: the one clock every simulated value is a function of.

Devices never read the wall clock. They ask a :class:`SimClock` for the
simulated time in seconds since the simulator started, so a test can freeze
it, step it by an hour or a day, or run it faster than real time, and the
values (uptime, drifting temperatures, offline episodes) follow exactly.
"""

from __future__ import annotations

import threading
import time

__all__ = ["SimClock"]


class SimClock:
    """Simulated seconds, running at ``rate`` times real time.

    ``start`` is the simulated time at creation. The clock is thread-safe:
    the bus thread reads it while a test steps it.
    """

    def __init__(self, start: float = 0.0, *, rate: float = 1.0) -> None:
        if rate <= 0:
            raise ValueError(f"rate must be more than 0, got {rate!r}")
        self._lock = threading.Lock()
        self._base = float(start)  # simulated time at _anchor
        self._anchor = time.perf_counter()
        self._rate = float(rate)
        self._frozen = False

    def now(self) -> float:
        """Simulated seconds."""
        if self._frozen:
            return self._base
        return self._base + (time.perf_counter() - self._anchor) * self._rate

    __call__ = now

    @property
    def frozen(self) -> bool:
        """True while :meth:`freeze` holds the clock still."""
        return self._frozen

    @property
    def rate(self) -> float:
        """Simulated seconds per real second."""
        return self._rate

    @rate.setter
    def rate(self, value: float) -> None:
        if value <= 0:
            raise ValueError(f"rate must be more than 0, got {value!r}")
        with self._lock:
            self._rebase()
            self._rate = float(value)

    def _rebase(self) -> None:
        self._base = self.now()
        self._anchor = time.perf_counter()

    def freeze(self) -> None:
        """Stop the clock where it is (values stop moving)."""
        with self._lock:
            self._rebase()
            self._frozen = True

    def resume(self) -> None:
        """Let a frozen clock run again from where it stopped."""
        with self._lock:
            self._rebase()
            self._frozen = False

    def advance(self, seconds: float) -> float:
        """Step the clock forward by ``seconds`` (frozen or not); returns the new time."""
        if seconds < 0:
            raise ValueError(f"the clock only goes forward, got {seconds!r} s")
        with self._lock:
            self._rebase()
            self._base += seconds
            return self._base

    def set(self, seconds: float) -> None:
        """Set the simulated time (going back is allowed: values are recomputed)."""
        with self._lock:
            self._base = float(seconds)
            self._anchor = time.perf_counter()

    def __repr__(self) -> str:
        state = "frozen" if self._frozen else f"x{self._rate:g}"
        return f"<SimClock t={self.now():.3f} s {state}>"
