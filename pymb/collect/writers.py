"""Batches written in parallel, acknowledged in the order they came.

PostgreSQL takes several transactions at once: each writer thread has a
connection of its own (:data:`pymb.collect.sqlstore.PG_WRITERS`; SQLite has
one writer). The collector's thread parses a batch and hands it over as a
:class:`Job`; it acknowledges a job's messages only once the job and every
job before it are committed (MQTT wants its acknowledgements in the order of
the messages). A writer that cannot reach the database holds its job and
tries again (0.5 s, backing off to 10 s) until it can, or until a stop.
"""

from __future__ import annotations

import collections
import threading
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field

from pymb.collect.rows import Batch
from pymb.collect.sqlstore import Store, StoreDown

__all__ = ["Job", "Message", "Writers"]

#: (connection generation, message id, QoS, topic, payload)
Message = tuple[int, int, int, str, bytes]
_BACKOFF = (0.5, 10.0)


@dataclass(eq=False)
class Job:
    """One batch: its messages and their rows."""

    messages: list[Message]
    batch: Batch
    done: threading.Event = field(default_factory=threading.Event)
    stored: int | None = None  #: new rows once committed; None: not written (a stop)
    error: BaseException | None = None


class Writers:
    """One thread per store, each writing one job at a time."""

    def __init__(self, stores: Sequence[Store], stop: threading.Event,
                 event: Callable[[str], None]) -> None:
        self.stores = list(stores)
        self.stop = stop
        self.event = event
        self.db_ok = True
        self._lock = threading.Lock()
        self._jobs: collections.deque[Job | None] = collections.deque()
        self._ready = threading.Condition(self._lock)
        self.pending: collections.deque[Job] = collections.deque()
        self.threads = [threading.Thread(target=self._work, args=(s,), daemon=True,
                                         name=f"pymb-collect-writer-{i}")
                        for i, s in enumerate(self.stores)]
        for t in self.threads:
            t.start()

    def batch(self) -> Batch:
        """An empty batch of the kind the stores take."""
        return self.stores[0].batch()

    def full(self) -> bool:
        """Every writer has a job and one more waits (parsed while they write)."""
        return len(self.pending) > len(self.stores)

    def submit(self, job: Job) -> None:
        """Hand a job to the next free writer."""
        self.pending.append(job)
        with self._ready:
            self._jobs.append(job)
            self._ready.notify()

    def finished(self) -> Iterator[Job]:
        """The jobs done, in the order they were submitted, up to the first one
        not done yet; raises the error a writer met (StoreRefused)."""
        while self.pending and self.pending[0].done.is_set():
            job = self.pending.popleft()
            if job.error is not None:
                raise job.error
            yield job

    def wait(self, timeout: float) -> None:
        """Wait for the oldest job (at most ``timeout`` seconds)."""
        if self.pending:
            self.pending[0].done.wait(timeout)

    def drain(self) -> None:
        """Wait for every job handed over (after a stop, a writer that cannot
        reach the database gives its job up at once)."""
        for job in list(self.pending):
            job.done.wait()

    def close(self) -> None:
        """End the threads and close the stores."""
        with self._ready:
            self._jobs.extend([None] * len(self.threads))
            self._ready.notify_all()
        for t in self.threads:
            t.join(30)
        for s in self.stores:
            s.close()

    def _work(self, store: Store) -> None:
        while True:
            with self._ready:
                while not self._jobs:
                    self._ready.wait()
                job = self._jobs.popleft()
            if job is None:
                return
            try:
                job.stored = self._write(store, job.batch)
            except BaseException as e:  # StoreRefused: the collector's thread raises it
                job.error = e
            finally:
                job.done.set()

    def _write(self, store: Store, batch: Batch) -> int | None:
        delay = _BACKOFF[0]
        while True:
            try:
                n = store.write(batch) if batch.rows else 0
            except StoreDown as e:
                with self._lock:
                    if self.db_ok:
                        self.event(f"the database cannot take the batch ({e}); holding "
                                   "its messages unacknowledged and trying again")
                    self.db_ok = False
                if self.stop.wait(delay):
                    return None
                delay = min(delay * 2, _BACKOFF[1])
                continue
            with self._lock:
                if not self.db_ok:
                    self.event(f"the database takes rows again ({store.target})")
                    self.db_ok = True
            return n
