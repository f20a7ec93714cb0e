"""The SQLite writer: samples and events in batches, by exception if asked,
within the size and age limits."""

from __future__ import annotations

import contextlib
import math
import os
import sqlite3
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TypeVar

from pymb.devices.readings import map_reading
from pymb.errors import InvalidArgument, OutputError
from pymb.store.block import PollBlock
from pymb.store.damage import damaged_error, is_corruption, set_aside_if_damaged
from pymb.store.eventlog import EVENT_INSERT
from pymb.store.faults import is_storage_fault, storage_error, vanished
from pymb.store.files import create, remove_stale_creations
from pymb.store.handoff import Handoff
from pymb.store.ids import SampleIds
from pymb.store.lock import WriterLock
from pymb.store.onchange import Changes, OnChange
from pymb.store.outbox import max_id
from pymb.store.reader import HubRow
from pymb.store.records import Event, PollSamples, Sample, SinkBase, own_sample_writes
from pymb.store.reserve import Reserve
from pymb.store.retention import Restamp, Retention
from pymb.store.rows import (
    ROWS_PER_INSERT,
    BoundRows,
    DeviceIds,
    block_binds,
    block_rows,
    bound_registers,
    channel_rows,
    insert_rows,
    sample_rows,
    unsupported_of,
)
from pymb.store.schema import MIN_BYTES, open_format

__all__ = ["SqliteSink"]

T = TypeVar("T")


class SqliteSink(SinkBase):
    """Writes samples and events to a SQLite database of format 2 (created if
    missing; a database of an older pymb format is refused, never mixed).

    ``max_bytes`` / ``max_age`` (seconds) bound the database: past the size
    (the database file and its WAL together, checked at every commit) or the
    age, the oldest samples and events are deleted and their pages reused.
    ``on_change`` stores readings by exception (see :class:`OnChange`).
    ``one_thread``: only the thread that makes the sink uses it (SQLite's
    thread check, on: another thread's use raises), else any thread, one at
    a time.

    If the database has an ``outbox(name TEXT PRIMARY KEY, sample_id INTEGER)``
    table (a forwarder's cursors: the last sample each has sent), trimming
    past the lowest cursor records a ``trim`` event saying how many samples
    (and which ids) were deleted before they were sent.
    """

    keeps_samples = False  #: see :class:`Sink`

    def __init__(self, path: str | os.PathLike[str], *, max_bytes: int | None = None,
                 max_age: float | None = None, on_change: OnChange | None = None,
                 one_thread: bool = False) -> None:
        self.path = Path(path)
        if max_bytes is not None and not max_bytes >= MIN_BYTES:
            raise InvalidArgument(f"the size limit must be at least {MIN_BYTES / 1e6:g} MB, "
                                  f"got {max_bytes / 1e6:g} MB")
        if max_age is not None and not (max_age > 0 and math.isfinite(max_age)):
            raise InvalidArgument(f"the age limit must be a positive number of days, "
                                  f"got {max_age / 86400:g}")
        self.max_bytes = max_bytes
        self.max_age = max_age
        self.on_change = on_change
        self.stored = 0  #: samples written (on-change: those that changed)
        self._on_commit: list[Callable[[int], None]] = []
        self._lock: WriterLock | None = None
        try:
            remove_stale_creations(self.path)
            if not self.path.exists():
                create(self.path)
            # A file this user may not write is refused here: SQLite would open
            # it read-only and fail at the first commit.
            os.close(os.open(self.path, os.O_RDWR | os.O_CLOEXEC))
            # One writer: refused here, before this process writes anything.
            self._lock = WriterLock(self.path)
            #: a damaged database found here and moved aside (the line that says so)
            self.notice = self._set_aside_if_damaged()
            self.db = sqlite3.connect(self.path, isolation_level=None,
                                      check_same_thread=one_thread)
        except (sqlite3.Error, OSError) as e:
            self._unlock()
            raise self._open_failed(e) from None
        try:
            self._open()
        except sqlite3.Error as e:
            self.db.close()
            self._unlock()
            raise self._open_failed(e) from None
        except InvalidArgument:
            self.db.close()
            self._unlock()
            raise
        self._device_ids = DeviceIds(self.db, self.path, self._begin)
        #: one thread at a time (the thread that runs the logger, and without
        #: ``one_thread`` any other: a library's)
        self._mutex = threading.RLock()
        self._handoff: Handoff | None = None  #: a forwarder's, see publish_live
        self._closed = False
        self._ids = SampleIds(self.db)
        self._changes: dict[int, Changes] = {}
        #: the first sample and event ids this sink writes (what restamp() may change)
        self._first_ids = tuple(int(self.db.execute(
            f"SELECT COALESCE(MAX(id), 0) + 1 FROM {t}").fetchone()[0])
            for t in ("samples", "events"))
        self._in_tx = False
        self._restamp: Restamp | None = None  # a re-stamping's steps left
        self._tx_bytes = 0  # registers written in the open batch (size limit only)
        self._reserve = Reserve(self.path)
        if max_bytes is not None:
            # Within the bound before the first sample (a lower bound than last
            # time, or a database that filled its disk: trimming makes room).
            try:
                self.retention.trim_at_open(self._reserve.give_up)
            except sqlite3.Error as e:
                self.db.close()
                self._unlock()
                raise self._open_failed(e) from None
        self._reserve.keep()
        if self.notice is not None:
            print(f"pymb log: {self.notice}", file=sys.stderr, flush=True)
            with self._mutex:
                self._event(Event(time.time(), time.monotonic(), "", None, "damaged", None,
                                  self.notice))
                self._commit()

    def _set_aside_if_damaged(self) -> str | None:
        """A damaged database moved aside, a new one in its place (the line that
        says so; None: nothing found)."""
        line = set_aside_if_damaged(self.path)
        if line is not None:
            self._unlock()  # the lock was the damaged file's
            self._lock = WriterLock(self.path)
        return line

    def _open_failed(self, e: Exception) -> Exception:
        """The error for a failed open: the storage's (exit 5: a service
        retries) or the file's content's (exit 2)."""
        if is_storage_fault(e):
            return storage_error(self.path, e, opening=True)
        if is_corruption(e):
            return damaged_error(self.path, getattr(self, "db", None), e)
        return InvalidArgument(f"cannot open the database {self.path}: {e}")

    def _open(self) -> None:
        page_size, wal_budget = open_format(self.db, self.path, self.max_bytes)
        #: the size and age limits, and the trimming that holds them
        self.retention = Retention(self.db, self.path, max_bytes=self.max_bytes,
                                   max_age=self.max_age, page_size=page_size,
                                   wal_budget=wal_budget)

    @property
    def trimmed(self) -> int:
        """Samples deleted by the size and age limits so far."""
        return self.retention.trimmed

    @property
    def wal_budget(self) -> int:
        """Bytes the WAL may reach under a size limit (a batch commits at a quarter)."""
        return self.retention.wal_budget

    @wal_budget.setter
    def wal_budget(self, value: int) -> None:
        self.retention.wal_budget = value

    def _begin(self) -> None:
        if not self._in_tx:
            # IMMEDIATE: the write lock is taken (waiting up to the busy timeout)
            # before the first read. A deferred transaction that reads and then
            # writes fails at once with "database is locked" if the forwarder
            # moved its outbox cursor in between (SQLITE_BUSY_SNAPSHOT in WAL mode).
            self.db.execute("BEGIN IMMEDIATE")
            self._in_tx = True

    def _failed(self, e: Exception) -> OutputError:
        if self._in_tx or self.db.in_transaction:
            with contextlib.suppress(sqlite3.Error):
                self.db.execute("ROLLBACK")
            self._in_tx = False
        self._device_ids.forget()  # ids inserted (views made) by the rolled-back batch
        self._changes.clear()  # what was "last stored" may be rolled back too
        if self._handoff is not None:  # what it handed over of the batch
            top = None
            if not self.db.in_transaction:  # rolled back: the file's top
                with contextlib.suppress(sqlite3.Error):
                    top = max_id(self.db)
            self._handoff.rolled_back(self._ids.last, top)
        if isinstance(e, OutputError):
            return e
        if is_storage_fault(e):
            return storage_error(self.path, e)
        if is_corruption(e):
            return damaged_error(self.path, getattr(self, "db", None), e)
        return OutputError(f"cannot write to {self.path}: {e}; everything committed before "
                           "is intact, the batch being written was lost")

    def write(self, sample: Sample) -> None:
        """Add one sample to the current batch. Under a size limit, a batch
        that grows past a quarter of the WAL budget is committed at once, so
        the bound holds at any write rate."""
        with self._mutex:
            try:
                self._make_room(1)
                self._write(sample)
                if self.max_bytes is not None:
                    self._tx_bytes += 2 * len(sample.data.registers) + 64
                    if self._tx_bytes >= self.wal_budget // 4:
                        self._commit()
            except (sqlite3.Error, OSError, OutputError) as e:
                raise self._failed(e) from None

    def write_batch(self, samples: Sequence[Sample]) -> None:
        """Add samples to the current batch, as :meth:`write` one by one
        would, in multi-row INSERTs: one statement (and one release of the
        GIL) for many rows. Under a size limit, a statement ends at the row
        that reaches a quarter of the WAL budget, where :meth:`write` would
        commit, and the commit follows it."""
        if self.on_change is not None or len(samples) < 2:
            for sample in samples:
                self.write(sample)
            return
        with self._mutex:
            self._write_rows(len(samples), lambda first: sample_rows(samples, first,
                                                                     self._device_ids))

    def write_block(self, block: PollSamples) -> None:
        """The rows bound straight from the block (no record a poll); on-change
        or in a subclass with writes of its own, as :class:`SinkBase` does."""
        if (self.on_change is not None or not isinstance(block, PollBlock)
                or own_sample_writes(type(self), SqliteSink)):
            return super().write_block(block)
        with self._mutex:  # (3 values a row where it can: a forwarder's hand-over takes 6)
            fast = None if self._handoff else block_binds(block, self._device_ids)
            self._write_rows(len(block), lambda first: fast.starting(first) if fast else
                             block_rows(block, first, self._device_ids))

    def _write_rows(self, rows: int, make: Callable[[int], BoundRows]) -> None:
        """``rows`` rows, ``make(first)`` (their ids from ``first`` on): their
        values as they are bound, each row's bytes of registers."""
        try:
            self._make_room(rows)
            bound = make(self._ids.take_many(rows))
            self._begin()
            if self.max_bytes is None:  # no WAL budget: statements of ROWS_PER_INSERT rows
                for i in range(0, rows, ROWS_PER_INSERT):
                    self.db.execute(*bound.statement(i, min(ROWS_PER_INSERT, rows - i)))
                self.stored += rows
            else:
                quarter = self.wal_budget // 4
                i = 0
                while i < rows:
                    # A statement ends where write() one by one would commit: at
                    # the row that brings the batch to a quarter of the WAL budget.
                    j, size = i, self._tx_bytes
                    while j < rows and j - i < ROWS_PER_INSERT:
                        size += bound.sizes[j] + 64
                        j += 1
                        if size >= quarter:
                            break
                    self.db.execute(*bound.statement(i, j - i))
                    self.stored += j - i
                    i = j
                    self._tx_bytes = size
                    if size >= quarter:
                        self._commit()
                        self._begin()
            if self._handoff is not None:
                self._handoff.wrote(self.db, bound.flat)
        except (sqlite3.Error, OSError, OutputError) as e:
            raise self._failed(e) from None

    def _insert(self, did: int, sample: Sample, registers: bytearray | None,
                unsupported: int, hub: Sequence[HubRow] = ()) -> int:
        row = (self._ids.take(), did, sample.time_utc, sample.monotonic, registers, unsupported)
        self.db.execute(insert_rows(1), row)
        if self._handoff is not None:  # a forwarder's (see publish_live)
            self._handoff.wrote(self.db, row, hub)
        return row[0]

    def _make_room(self, n: int) -> None:
        """Live: the mark covers ``n`` more ids (committed first if it must move)."""
        if self._ids.short(n):
            self._begin()
            mark = self._ids.write_mark(self.db, n)
            self._commit()
            self._ids.marked(mark)

    def _write(self, sample: Sample) -> None:
        data = map_reading(sample.data)
        did, channels, size = self._device_ids.id_of(sample.device, data)
        self._begin()
        hub: list[HubRow] = []
        if self.on_change is not None:
            rules = self._changes.get(did)
            if rules is None:
                rules = self._changes[did] = Changes.of(self.on_change, sample.device, channels)
            pick = rules.changed(data, sample.monotonic)
            if not pick:
                return
            if channels:  # stored by channel: the channels picked, as rows of hub_changes
                hub = channel_rows(data, pick)
        sid = self._insert(did, sample, None if hub else bound_registers(data, size),
                           unsupported_of(data), hub)
        if hub:
            self.db.executemany("INSERT INTO hub_changes VALUES (?, ?, ?, ?, ?)",
                                [(did, ch, sample.time_utc, sid, b) for ch, b in hub])
        self.stored += 1

    def event(self, event: Event) -> None:
        """Add one event to the current batch."""
        with self._mutex:
            try:
                self._event(event)
            except (sqlite3.Error, OSError, OutputError) as e:
                raise self._failed(e) from None

    def _event(self, event: Event) -> None:
        did = None if event.device is None else self._device_ids.id_of(event.device, event)[0]
        self._begin()
        self.db.execute(
            EVENT_INSERT,
            (event.time_utc, event.monotonic, event.bus, did, event.kind, event.code,
             event.message))

    def restamp(self, offset: float) -> bool:
        """The wall clock stepped: the samples and events this sink wrote with
        the old clock get the time their monotonic time gives with the new
        ``offset`` (wall time less monotonic time). In bounded steps, one
        with each commit (a step's work and WAL bounded however long the run
        was); a later step starts over with its offset."""
        with self._mutex:
            try:
                tops = [int(self.db.execute(f"SELECT COALESCE(MAX(id), 0) FROM {t}").fetchone()[0])
                        for t in ("samples", "events")]
            except sqlite3.Error as e:
                raise self._failed(e) from None
            self._restamp = Restamp(offset, [*self._first_ids], tops)
        return True

    def _restamp_step(self) -> None:
        """One bounded step of a pending re-stamping, in the open batch."""
        if self._restamp is not None:
            self._begin()
            if self._restamp.step(self.db, self.wal_budget // 4):
                self._restamp = None

    @property
    def restamping(self) -> bool:
        """True while a re-stamping has steps left (see :meth:`restamp`)."""
        return self._restamp is not None

    def commit(self) -> None:
        """Commit the batch, then hold the size limit (database and WAL) and,
        every few seconds, the age limit."""
        with self._mutex:
            try:
                self._commit()
            except (sqlite3.Error, OSError, OutputError) as e:
                raise self._failed(e) from None

    def in_batch(self, fn: Callable[[sqlite3.Connection], T], commit: bool) -> T:
        """``fn(db)`` inside the current batch, under the writer's lock; the
        batch is committed after it when ``commit`` (the record of writes)."""
        with self._mutex:
            try:
                self._begin()
                out = fn(self.db)
                if commit:
                    self._commit()
                return out
            except (sqlite3.Error, OSError, OutputError) as e:
                raise self._failed(e) from None

    def on_commit(self, callback: Callable[[int], None]) -> None:
        """Call ``callback(max_id)`` after each commit, with the highest
        sample id then durable (0: none): at :meth:`commit`, at
        :meth:`close`, and where a size limit commits within a batch. A
        forwarder wakes on it; an exception from it is the committer's."""
        self._on_commit.append(callback)

    def _commit(self) -> None:
        self._restamp_step()
        self._commit_batch()
        if self._on_commit:
            top = max_id(self.db)
            for callback in self._on_commit:
                callback(top)

    def _commit_batch(self) -> None:
        if self._in_tx:
            self._check()  # SQLite would write on into the deleted files
            self.db.execute("COMMIT")
            self._in_tx = False
        self._tx_bytes = 0
        r = self.retention
        if r.max_bytes is not None:
            if r.wal_bytes() > r.wal_budget:
                # A reader held the WAL back: catch up if it has let go (without
                # waiting for it: a forwarder may be reading).
                r.checkpoint()
            if r.over_room():
                self.trim()
                return
        if r.age_due():
            self.trim()

    def check(self) -> None:
        """Raise :class:`OutputError` if the database's file or directory was
        removed (a logger with nothing to commit looks every second)."""
        with self._mutex:
            self._check()

    def _check(self) -> None:
        gone = vanished(self.path)
        if gone is not None:
            raise OutputError(f"cannot write to {self.path}: {gone}; the samples logged into "
                              "it went with it; restore the directory (or log to another --out)")

    def trim(self) -> int:
        """Delete the oldest data beyond the limits; returns samples deleted."""
        with self._mutex:
            try:
                return self.retention.trim()
            except (sqlite3.Error, OSError, OutputError) as e:
                raise self._failed(e) from None

    def _unlock(self) -> None:
        if self._lock is not None:
            self._lock.release()
            self._lock = None

    def max_id(self) -> int:
        """The highest sample id written (0: none), this batch's included."""
        with self._mutex:
            return max_id(self.db)

    @property
    def closed(self) -> bool:
        """True once :meth:`close` ran."""
        return self._closed

    @property
    def last_id(self) -> int:
        """The highest sample id handed out (0: none; not a query)."""
        return self._ids.last

    def publish_live(self, handoff: Handoff) -> None:
        """Hand each sample written from now on (a forwarder publishes it before
        its commit: its id is under a durable mark, :mod:`pymb.store.ids`,
        never handed out twice) and each commit's top id to ``handoff``."""
        with self._mutex:
            try:
                self._commit()
                self._ids.live = True
                self._make_room(1)
                handoff.attach(self._ids.last, max_id(self.db))
            except (sqlite3.Error, OSError, OutputError) as e:
                raise self._failed(e) from None
            self._handoff = handoff
            self._on_commit.append(handoff.commit_done)

    def close(self) -> None:
        """Commit what is pending, close the database and let the next writer in."""
        with self._mutex:
            try:
                settled = None
                while self._restamp is not None:  # its steps, each committed
                    self.commit()
                if self._ids.live:
                    self._begin()
                    settled = self._ids.write_settled(self.db)
                self.commit()
                if settled is not None:
                    self._ids.marked(settled)
            finally:
                self._closed = True
                self.db.close()
                self._unlock()
                if self._handoff is not None:
                    self._handoff.writer_closed()
