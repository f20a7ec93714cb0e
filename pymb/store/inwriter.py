"""Another thread's work on the writer's database, done in the writer's own
thread: a command desk's record of write commands (:mod:`pymb.store.commands`)
is asked for here and run by the writer between its writes, inside its open
batch, so no SQLite connection crosses a thread (a logger run with a
forwarder opens its connection with SQLite's thread check on).

What a request writes without its commit goes in with the writer's batch,
committed within :data:`COMMIT_AFTER` (:meth:`InWriter.serve` says when)
even if the logger has nothing else to commit (a device gone silent).

The asker waits for its answer ``wait`` seconds at most: a request the
writer has not started by then is taken back and fails with
:class:`~pymb.errors.OutputError` (a command not put on record is not
executed); one it has started is waited for (SQLite's busy timeout bounds
it). Once the writer is closed every request fails at once.
"""

from __future__ import annotations

import collections
import concurrent.futures
import sqlite3
import threading
import time
from collections.abc import Callable
from typing import Any, TypeVar

from pymb.errors import OutputError
from pymb.store.writer import SqliteSink

__all__ = ["COMMIT_AFTER", "REQUEST_WAIT", "InWriter"]

T = TypeVar("T")

REQUEST_WAIT = 10.0  #: seconds a request waits for the writer to take it, at most
COMMIT_AFTER = 1.0  #: seconds what a request wrote waits for a commit, at most

_Request = tuple[Callable[[sqlite3.Connection], Any], bool, "concurrent.futures.Future[Any]"]


class InWriter:
    """``fn(db)`` in ``sink``'s batch, in the writer's thread (the one that
    makes this): called there, at once; from another thread, asked for and
    run at the writer's next :meth:`serve`. The same call as
    :meth:`SqliteSink.in_batch <pymb.store.SqliteSink.in_batch>` (a
    :class:`~pymb.store.commands.CommandLog`'s way to the file)."""

    def __init__(self, sink: SqliteSink, wait: float = REQUEST_WAIT) -> None:
        self.sink = sink
        self.wait = wait
        #: ends the writer's idle wait (its loop's: :meth:`pymb.logger.Logger.wake`)
        self.wake: Callable[[], None] = lambda: None
        self._writer = threading.get_ident()
        self._lock = threading.Lock()
        self._asked: collections.deque[_Request] = collections.deque()
        self._closed = False
        self._unsaved: float | None = None  # when a request wrote without a commit since

    def __call__(self, fn: Callable[[sqlite3.Connection], T], commit: bool, /) -> T:
        """``fn(db)`` in the writer's batch, committed after it when ``commit``."""
        if threading.get_ident() == self._writer:
            return self.sink.in_batch(fn, commit)
        done: concurrent.futures.Future[T] = concurrent.futures.Future()
        with self._lock:
            if self._closed:
                raise self._stopped()
            self._asked.append((fn, commit, done))
        self.wake()
        try:
            return done.result(self.wait)
        except concurrent.futures.TimeoutError:
            if done.cancel():  # not started: taken back
                raise OutputError(f"cannot write to {self.sink.path}: the logger's writer "
                                  f"did not take it within {self.wait:g} s") from None
            return done.result()  # started: its answer comes

    def serve(self) -> bool:
        """Run what was asked, in order (the writer's thread, between its
        writes); True when what a request wrote has waited :data:`COMMIT_AFTER`
        for a commit: the writer should commit now."""
        while True:
            with self._lock:
                if not self._asked:
                    break
                fn, commit, done = self._asked.popleft()
            if not done.set_running_or_notify_cancel():
                continue  # taken back
            changes = self.sink.db.total_changes
            try:
                out = self.sink.in_batch(fn, commit)
            except Exception as e:  # the asker's: an OutputError (the batch rolled back)
                done.set_exception(e)
                continue
            except BaseException:
                done.set_exception(self._stopped())
                raise
            if not commit and self._unsaved is None and self.sink.db.total_changes != changes:
                self._unsaved = time.monotonic()
            done.set_result(out)
        return self._unsaved is not None and time.monotonic() - self._unsaved >= COMMIT_AFTER

    def committed(self) -> None:
        """The writer committed (its on-commit hook): what requests wrote is in the file."""
        self._unsaved = None

    def close(self) -> None:
        """The writer is closed: what waits fails, and so does any later request."""
        with self._lock:
            self._closed = True
            asked, self._asked = self._asked, collections.deque()
        for _, _, done in asked:
            if done.set_running_or_notify_cancel():
                done.set_exception(self._stopped())

    def _stopped(self) -> OutputError:
        return OutputError(f"cannot write to {self.sink.path}: the logger has stopped")
