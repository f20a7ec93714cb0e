"""What the asyncio tests share: waiting for an event inside a coroutine,
measuring the event loop's lag (the bench's ticker), and counting what a
process holds."""

from __future__ import annotations

import asyncio
import contextlib
import os
import threading
from collections.abc import Callable
from typing import TypeVar

from pymb.bench.aioworker import Ticker

__all__ = ["Ticker", "fds", "pymb_threads", "until"]

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
