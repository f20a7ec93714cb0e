"""The worker thread that owns one line: every blocking call of one client
(and of the device facades on it) runs here, one at a time, in the order
the event loop asked for them.

A job is a blocking callable and the asyncio future that waits for it. The
worker takes jobs first in, first out; a job whose future was cancelled
before the worker reached it is dropped unrun (nothing was sent); a job
already running finishes (its request and its reply complete on the line,
within the client's timeout) and its result is dropped. The result goes
back to the future's loop with ``call_soon_threadsafe``: the loop never
waits on the wire, a descriptor or the client's lock (only, for
microseconds, on the lock that starts and ends the worker thread).

The thread starts with the first job and ends as soon as it has nothing to
do and the line is closed, so a closed client holds no thread.
"""

from __future__ import annotations

import asyncio
import contextlib
import queue
import threading
from collections.abc import Callable
from typing import Any, ParamSpec, TypeVar

from pymb.client import Client

__all__ = ["LineWorker"]

P = ParamSpec("P")
R = TypeVar("R")

# future (None: nobody waits), loop, function, args, kwargs
_Job = tuple["asyncio.Future[Any] | None", "asyncio.AbstractEventLoop | None",
             Callable[..., Any], tuple[Any, ...], dict[str, Any]]


def _settle(fut: asyncio.Future[Any], ok: bool, value: Any) -> None:
    """On the loop: hand the worker's outcome to a future still waiting."""
    if fut.done():  # cancelled while its job ran: the outcome is dropped
        return
    if ok:
        fut.set_result(value)
    else:
        fut.set_exception(value)


class LineWorker:
    """The worker of one blocking :class:`~pymb.Client` (``blocking``);
    ``name`` names its thread."""

    def __init__(self, blocking: Client, name: str) -> None:
        self.blocking = blocking
        self.name = name
        self._jobs: queue.SimpleQueue[_Job] = queue.SimpleQueue()
        self._lock = threading.Lock()  # starting and ending the thread
        self._thread: threading.Thread | None = None
        self._ended: threading.Thread | None = None  # the last thread that ended
        self.started = 0  #: worker threads started so far

    def submit(self, fn: Callable[P, R], /, *args: P.args,
               **kwargs: P.kwargs) -> asyncio.Future[R]:
        """Queue ``fn(*args, **kwargs)`` behind the line's other jobs; the
        returned future (of the running loop) gets its result or exception."""
        loop = asyncio.get_running_loop()
        fut: asyncio.Future[R] = loop.create_future()
        self._put((fut, loop, fn, args, kwargs))
        return fut

    def post(self, fn: Callable[..., Any], *args: Any) -> None:
        """Queue ``fn(*args)`` with nobody waiting (from any thread; for a
        client dropped while open). Its errors are dropped."""
        self._put((None, None, fn, args, {}))

    def _put(self, job: _Job) -> None:
        with self._lock:
            self._jobs.put(job)
            if self._thread is None:
                t = threading.Thread(target=self._run, name=self.name, daemon=True)
                t.start()
                self._thread = t
                self.started += 1

    def join_ended(self, timeout: float = 5.0) -> None:
        """Wait for the thread that last ended to be gone (it has nothing
        left to do but return: microseconds)."""
        with self._lock:
            t, self._ended = self._ended, None
        if t is not None and t is not threading.current_thread():
            t.join(timeout)

    def _end_if_idle(self) -> bool:
        # Nothing queued and the line closed ends the thread; decided under
        # the lock _put takes, so a job queued meanwhile starts a new one.
        with self._lock:
            if not self._jobs.empty() or self.blocking.connected:
                return False
            self._thread = None
            self._ended = threading.current_thread()
            return True

    def _run(self) -> None:
        jobs = self._jobs
        while True:
            job = jobs.get()  # waits in C, the GIL released, while the line is open
            outcome = self._do(job)
            del job  # hold no request, reply or traceback while idle
            # Decided before the result goes out, so whoever awaited it
            # (close()) can join the thread.
            end = not self.blocking.connected and self._end_if_idle()
            if outcome is not None:
                fut, loop, ok, value = outcome
                with contextlib.suppress(RuntimeError):  # a closed loop: nobody to tell
                    loop.call_soon_threadsafe(_settle, fut, ok, value)
                del outcome, fut, value
            if end:
                return

    @staticmethod
    def _do(job: _Job) -> tuple[asyncio.Future[Any], asyncio.AbstractEventLoop, bool, Any] | None:
        """Run a job; its outcome for the loop, or None when nobody waits."""
        fut, loop, fn, args, kwargs = job
        if fut is not None and fut.cancelled():
            return None  # cancelled before it started: nothing was sent
        try:
            value, ok = fn(*args, **kwargs), True
        except StopIteration as e:  # a future cannot hold one
            value, ok = RuntimeError(f"{fn!r} raised StopIteration: {e}"), False
        except BaseException as e:  # the worker goes on, whatever the job raised
            value, ok = e, False
        if fut is None or loop is None:
            return None
        return fut, loop, ok, value
