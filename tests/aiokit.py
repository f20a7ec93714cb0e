"""What the asyncio tests share: waiting for an event inside a coroutine,
measuring the event loop's lag, and counting what a process holds."""

from __future__ import annotations

import asyncio
import contextlib
import os
import statistics
import threading
from collections.abc import Callable
from typing import TypeVar

_T = TypeVar("_T")


async def until(event: Callable[[], _T], what: str, timeout: float = 10.0) -> _T:
    """Poll ``event()`` (every 2 ms, giving the loop its turn) until it is
    true and return it; fail naming ``what`` after ``timeout`` seconds."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while not (got := event()):
        if loop.time() > deadline:
            raise AssertionError(f"timed out after {timeout:g} s waiting for {what}")
        await asyncio.sleep(0.002)
    return got


class Ticker:
    """A 10 ms ticker on the running loop: how late each tick fires is the
    loop's lag (what a blocked loop shows first)."""

    def __init__(self, period: float = 0.010) -> None:
        self.period = period
        self.late: list[float] = []
        self._task: asyncio.Task[None] | None = None

    async def _run(self) -> None:
        loop = asyncio.get_running_loop()
        due = loop.time() + self.period
        while True:
            await asyncio.sleep(max(0.0, due - loop.time()))
            now = loop.time()
            self.late.append(now - due)
            due = max(due + self.period, now)  # a long stall is one late tick

    def start(self) -> Ticker:
        """Start ticking on the running loop."""
        self._task = asyncio.get_running_loop().create_task(self._run())
        return self

    async def stop(self) -> None:
        """Stop ticking."""
        assert self._task is not None
        self._task.cancel()
        await asyncio.gather(self._task, return_exceptions=True)

    def p(self, q: float) -> float:
        """The ``q`` quantile of the lateness, seconds (q in 0..1)."""
        if len(self.late) < 2:
            return max(self.late, default=0.0)
        return statistics.quantiles(self.late, n=100, method="inclusive")[round(q * 100) - 1]


def pymb_threads() -> list[str]:
    """The names of the live pymb.aio worker threads of this process."""
    return [t.name for t in threading.enumerate() if t.name.startswith("pymb-aio")]


def fds() -> set[str]:
    """What this process's descriptors point at."""
    out = set()
    for fd in os.listdir("/proc/self/fd"):
        with contextlib.suppress(OSError):
            out.add(f"{fd} {os.readlink(f'/proc/self/fd/{fd}')}")
    return out
