"""The store's side of store-and-forward: what a forwarder reads from and
writes to in the logger's SQLite file, so that no SQL is written outside the
store.

The samples come from :func:`pymb.store.reader.stored_after` (the one reader
of the storage format) as :class:`pymb.store.StoredSample` of map readings, behind
:meth:`Outbox.samples_after` and :meth:`Outbox.latest`. The durable outbox
cursor and the Sparkplug ``bdSeq`` are two small tables of the same file:

``outbox(name TEXT PRIMARY KEY, sample_id INTEGER)``
    per destination (``mqtt://ADDRESS:PORT/PROFILE/[GROUP/]NODE``, the address
    the broker's name resolved to: see :mod:`pymb.fleet.forwarder`), the highest sample
    id up to which every sample was acknowledged by the broker. The size and
    age limits of the database (:meth:`pymb.store.SqliteSink.trim`) look at
    the lowest cursor and record an event when they delete samples past it.
``fleet_state(key TEXT PRIMARY KEY, value INTEGER)``
    the Sparkplug ``bdSeq`` of the last connection, so that it keeps
    counting across restarts.
"""

from __future__ import annotations

import contextlib
import os
import sqlite3
import threading
from collections.abc import Iterator
from contextlib import AbstractContextManager
from pathlib import Path
from typing import Protocol

from pymb.store.reader import stored_after
from pymb.store.records import StoredSample

__all__ = ["STATE_COMMIT_WAIT", "LiveWriter", "Outbox", "last_sample_id", "max_id", "set_cursor_on"]

STATE_COMMIT_WAIT = 5.0  #: seconds set_state waits for a writer's commit, at most


class LiveWriter(Protocol):
    """What an outbox and a forwarder need of the writer of the file in this
    process (:class:`pymb.store.SqliteSink`)."""

    @property
    def closed(self) -> bool:
        """True once the writer closed."""
        ...

    def publish_live(self) -> None:
        """Let readers see the samples of the open batch."""
        ...

    def reading(self) -> AbstractContextManager[sqlite3.Connection | None]:
        """The writer's connection while no write runs (None once closed)."""
        ...


class Outbox:
    """A read connection to a pymb SQLite file, plus the outbox tables.

    With ``writer`` (the :class:`pymb.store.SqliteSink` writing the file, in
    this process, after its ``publish_live()``), everything goes through the
    writer's connection between its writes: the samples of its open batch
    are read too (published before their commit: their ids are under the
    writer's durable mark), and what this writes goes in with its batch
    (``set_state`` waits for that batch's commit). Once the writer is
    closed, its own connection takes over.
    """

    def __init__(self, path: str, writer: LiveWriter | None = None) -> None:
        self.path = path
        self.writer = writer
        self._own: sqlite3.Connection | None = None
        #: set by the writer's owner after each commit (see :meth:`set_state`)
        self.committed = threading.Event()
        #: set when a write here must be committed soon (the writer's owner looks)
        self.commit_wanted = threading.Event()
        with self._db() as db:
            db.execute("CREATE TABLE IF NOT EXISTS outbox("
                       "name TEXT PRIMARY KEY, sample_id INTEGER NOT NULL)")
            db.execute("CREATE TABLE IF NOT EXISTS fleet_state("
                       "key TEXT PRIMARY KEY, value INTEGER NOT NULL)")

    @property
    def live(self) -> bool:
        """True while reads go through a running writer (uncommitted samples too)."""
        return self.writer is not None and not self.writer.closed

    @property
    def db(self) -> sqlite3.Connection:
        """This outbox's own connection (opened at the first use)."""
        if self._own is None:
            self._own = sqlite3.connect(self.path, timeout=30, isolation_level=None,
                                        check_same_thread=False)
            self._own.execute("PRAGMA busy_timeout = 30000")
        return self._own

    @contextlib.contextmanager
    def _db(self) -> Iterator[sqlite3.Connection]:
        if self.writer is not None:
            with self.writer.reading() as db:
                if db is not None:
                    yield db
                    return
        yield self.db

    def close(self) -> None:
        """Release the connection."""
        if self._own is not None:
            self._own.close()

    # -- the cursor and the state --------------------------------------------------

    def cursor(self, name: str) -> int:
        """The outbox cursor of a destination (0: nothing sent yet)."""
        got = self.cursor_or_none(name)
        return 0 if got is None else got

    def cursor_or_none(self, name: str) -> int | None:
        """The outbox cursor of a destination, None when it has none."""
        with self._db() as db:
            row = db.execute("SELECT sample_id FROM outbox WHERE name = ?", (name,)).fetchone()
        return None if row is None else int(row[0])

    def rename_cursor(self, old: str, new: str) -> None:
        """Key a destination's cursor anew (kept if ``new`` has one already)."""
        with self._db() as db:
            db.execute("UPDATE OR IGNORE outbox SET name = ? WHERE name = ?", (new, old))
            db.execute("DELETE FROM outbox WHERE name = ?", (old,))

    def set_cursor(self, name: str, sample_id: int) -> None:
        """Advance the cursor (durably: one small transaction; with a writer,
        in its batch)."""
        with self._db() as db:
            set_cursor_on(db, name, sample_id)

    def state(self, key: str) -> int | None:
        """A remembered integer (the Sparkplug bdSeq)."""
        with self._db() as db:
            row = db.execute("SELECT value FROM fleet_state WHERE key = ?", (key,)).fetchone()
        return None if row is None else int(row[0])

    def set_state(self, key: str, value: int) -> None:
        """Remember an integer durably (with a writer in a batch: in the batch,
        then asks for its commit and waits for it, a few seconds at most)."""
        with self._db() as db:
            self.committed.clear()
            db.execute("INSERT OR REPLACE INTO fleet_state VALUES (?, ?)", (key, value))
            waiting = db.in_transaction
        if waiting:
            self.commit_wanted.set()
            self.committed.wait(STATE_COMMIT_WAIT)

    # -- the samples ---------------------------------------------------------------

    def max_id(self) -> int:
        """The highest sample id (0: none): committed, or with a writer, written."""
        with self._db() as db:
            return max_id(db)

    def ids_after(self, sample_id: int) -> set[int]:
        """The ids of the samples above ``sample_id``."""
        with self._db() as db:
            return {int(i) for (i,) in db.execute("SELECT id FROM samples WHERE id > ?",
                                                  (sample_id,))}

    def oldest_after(self, sample_id: int) -> tuple[int, float] | None:
        """(count, time of the oldest) of the samples after an id. The count of
        a long backlog takes a while: it runs on this outbox's own connection
        (never holding a writer up), plus a writer's samples not yet committed."""
        count, oldest, top = self.db.execute(
            "SELECT COUNT(*), MIN(time_utc), (SELECT MAX(id) FROM samples) FROM samples "
            "WHERE id > ?", (sample_id,)).fetchone()
        if self.live:
            after = max(sample_id, int(top or 0))
            with self._db() as db:  # the batch: a short range of ids
                n, first = db.execute("SELECT COUNT(*), MIN(time_utc) FROM samples "
                                      "WHERE id > ?", (after,)).fetchone()
            count += n
            oldest = first if oldest is None else oldest
        return None if not count else (int(count), float(oldest))

    def devices(self) -> list[tuple[str, str, int]]:
        """(name, type, address) of every device the file has samples of, once
        each (a map device has a devices row per polling group)."""
        with self._db() as db:
            return [(str(n), str(t), int(a)) for n, t, a in db.execute(
                "SELECT name, type, address FROM devices GROUP BY name, type, address "
                "ORDER BY MIN(id)")]

    def latest(self, device: str) -> StoredSample | None:
        """The newest sample of a device (looked up in what is committed on
        this outbox's own connection, never holding a writer up; then in a
        writer's batch, a short range of ids)."""
        find = ("SELECT MAX(s.id) FROM samples s JOIN devices d ON d.id = s.device_id "
                "WHERE d.name = ? AND s.id > ?")
        top = int(self.db.execute("SELECT COALESCE(MAX(id), 0) FROM samples").fetchone()[0])
        found = self.db.execute(find, (device, 0)).fetchone()[0]
        if self.live:
            with self._db() as db:
                found = db.execute(find, (device, top)).fetchone()[0] or found
        if found is None:
            return None
        got = self.samples_after(int(found) - 1, 1)
        return got[0] if got else None

    def samples_after(self, sample_id: int, limit: int,
                      before: int | None = None) -> list[StoredSample]:
        """The samples with ids above ``sample_id`` (and below ``before``), in
        id order, at most ``limit``: pymb.store's reader of its storage format,
        in one snapshot (committed ones; with a writer, its batch's too)."""
        with self._db() as db:
            if db is not self._own:  # the writer's: no other write runs meanwhile
                return stored_after(db, sample_id, limit, before)
            db.execute("BEGIN")  # one snapshot for the samples and their values
            try:
                return stored_after(db, sample_id, limit, before)
            finally:
                db.execute("COMMIT")


def set_cursor_on(db: sqlite3.Connection, name: str, sample_id: int) -> None:
    """Advance a destination's cursor through any connection to the file (the
    writer's, inside its batch: :meth:`pymb.store.SqliteSink.set_outbox_cursor`);
    it never moves back."""
    db.execute("INSERT INTO outbox VALUES (?, ?) ON CONFLICT(name) DO UPDATE SET "
               "sample_id = MAX(sample_id, excluded.sample_id)", (name, sample_id))


def max_id(db: sqlite3.Connection) -> int:
    """The highest committed sample id (0: none)."""
    return int(db.execute("SELECT COALESCE(MAX(id), 0) FROM samples").fetchone()[0])


def last_sample_id(path: str) -> int:
    """The highest sample id already in the file at ``path`` (0: none, no such
    file, or not a pymb database), read without writing to it."""
    if not os.path.isfile(path):
        return 0
    try:
        con = sqlite3.connect(Path(path).resolve().as_uri() + "?mode=ro", uri=True)
        try:
            return max_id(con)
        finally:
            con.close()
    except sqlite3.Error:
        return 0
