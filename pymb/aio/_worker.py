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

A request (:meth:`LineWorker.request`, not a setting or the life cycle's
:meth:`LineWorker.submit`) queued when :meth:`LineWorker.cut` is called
(a close()) never runs: its future gets a ModbusConnectionError; the one
running then is stopped on the line (within 50 ms).

The thread starts with the first job and ends as soon as it has nothing to
do and the line is closed, so a closed client holds no thread.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import queue
import threading
from collections.abc import Callable
from functools import partial
from typing import ParamSpec, TypeVar

from pymb.client import Client
from pymb.client.core import stop_waiting
from pymb.errors import ModbusConnectionError

__all__ = ["LineWorker"]

P = ParamSpec("P")
R = TypeVar("R")

#: the loop and what it is to call there: the outcome of a job
_Outcome = tuple[asyncio.AbstractEventLoop, Callable[[], None]]
#: a job, run on the worker: its outcome for a loop, None when nobody waits
_Job = Callable[[], "_Outcome | None"]


def _settle(fut: asyncio.Future[R], value: R) -> None:
    """On the loop: hand the worker's result to a future still waiting."""
    if not fut.done():  # cancelled while its job ran: the outcome is dropped
        fut.set_result(value)


def _fail(fut: asyncio.Future[R], error: BaseException) -> None:
    """On the loop: hand the worker's exception to a future still waiting."""
    if not fut.done():
        fut.set_exception(error)


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
        self._queued = 0  # requests queued so far
        self._cut = 0  # requests queued before the last cut(): never run
        self._running = False  # a job runs on the worker now

    def submit(self, fn: Callable[P, R], /, *args: P.args,
               **kwargs: P.kwargs) -> asyncio.Future[R]:
        """Queue ``fn(*args, **kwargs)`` behind the line's other jobs; the
        returned future (of the running loop) gets its result or exception.
        For the life cycle and settings: a :meth:`cut` leaves it queued."""
        return self._submit(None, fn, *args, **kwargs)

    def request(self, fn: Callable[P, R], /, *args: P.args,
                **kwargs: P.kwargs) -> asyncio.Future[R]:
        """:meth:`submit` for a call that uses the line: a :meth:`cut` before
        its turn fails it unrun."""
        self._queued += 1
        return self._submit(self._queued, fn, *args, **kwargs)

    def cut(self) -> None:
        """A close() is coming (from the loop): the requests queued now never
        run, and the job running now is stopped on the line (its wait ends
        within 50 ms with :class:`~pymb.ModbusConnectionError`)."""
        self._cut = self._queued
        if self._running:
            stop_waiting(self.blocking)

    def _submit(self, seq: int | None, fn: Callable[P, R], /, *args: P.args,
                **kwargs: P.kwargs) -> asyncio.Future[R]:
        loop = asyncio.get_running_loop()
        fut: asyncio.Future[R] = loop.create_future()

        def job() -> _Outcome | None:
            if fut.cancelled():
                return None  # cancelled before it started: nothing was sent
            if seq is not None and seq <= self._cut:
                port = self.blocking.port
                return loop, partial(_fail, fut, ModbusConnectionError(
                    f"{port}: the client was closed before this request's turn",
                    errno=errno.ECANCELED, port=port))
            try:
                value = fn(*args, **kwargs)
            except StopIteration as e:  # a future cannot hold one
                return loop, partial(_fail, fut, RuntimeError(f"{fn!r} raised StopIteration: {e}"))
            except BaseException as e:  # the worker goes on, whatever the job raised
                return loop, partial(_fail, fut, e)
            return loop, partial(_settle, fut, value)

        self._put(job)
        return fut

    def post(self, fn: Callable[P, object], *args: P.args, **kwargs: P.kwargs) -> None:
        """Queue ``fn(*args)`` with nobody waiting (from any thread; for a
        client dropped while open). Its errors are dropped."""

        def job() -> None:
            with contextlib.suppress(BaseException):  # the worker goes on
                fn(*args, **kwargs)

        self._put(job)

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
            self._running = True
            try:
                outcome = job()
            finally:
                self._running = False
            del job  # hold no request, reply or traceback while idle
            # Decided before the result goes out, so whoever awaited it
            # (close()) can join the thread.
            end = not self.blocking.connected and self._end_if_idle()
            if outcome is not None:
                loop, settle = outcome
                with contextlib.suppress(RuntimeError):  # a closed loop: nobody to tell
                    loop.call_soon_threadsafe(settle)
                del outcome, settle
            if end:
                return
