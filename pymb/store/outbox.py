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

import os
import sqlite3
from pathlib import Path
from typing import Protocol

from pymb.store.handoff import Handoff, Written
from pymb.store.reader import RowDecoder, stored_after
from pymb.store.records import StoredSample

__all__ = ["STATE_COMMIT_WAIT", "LiveWriter", "Outbox", "last_sample_id", "max_id",
           "set_cursor_on", "write_pending"]

STATE_COMMIT_WAIT = 5.0  #: seconds set_state waits for a writer's commit, at most


class LiveWriter(Protocol):
    """What a forwarder needs of the writer of the file in this process
    (:class:`pymb.store.SqliteSink`)."""

    def publish_live(self, handoff: Handoff) -> None:
        """Hand every sample written from now on to ``handoff``, and each
        commit's highest durable id."""
        ...


class Outbox:
    """A read connection to a pymb SQLite file, plus the outbox tables; one
    thread uses it (its connection is made at the first use, in that thread).

    With ``handoff`` (from the :class:`pymb.store.SqliteSink` writing the
    file, in this process, see :mod:`pymb.store.handoff`), the samples of
    the writer's open batch come from there too, and what this writes goes
    in with the writer's next batch (``set_state`` waits for its commit).
    Once the writer is closed, this connection reads and writes it all.
    """

    def __init__(self, path: str, handoff: Handoff | None = None) -> None:
        self.path = path
        self.handoff = handoff
        self._own: sqlite3.Connection | None = None
        self._rows = RowDecoder()  # the handoff's samples, decoded here
        db = sqlite3.connect(path, timeout=30, isolation_level=None)  # this thread's
        try:
            db.execute("CREATE TABLE IF NOT EXISTS outbox("
                       "name TEXT PRIMARY KEY, sample_id INTEGER NOT NULL)")
            db.execute("CREATE TABLE IF NOT EXISTS fleet_state("
                       "key TEXT PRIMARY KEY, value INTEGER NOT NULL)")
        finally:
            db.close()

    @property
    def live(self) -> bool:
        """True while a running writer hands over its samples (uncommitted ones too)."""
        return self.handoff is not None and not self.handoff.closed

    @property
    def db(self) -> sqlite3.Connection:
        """This outbox's own connection (opened at the first use, for that thread)."""
        if self._own is None:
            self._own = sqlite3.connect(self.path, timeout=30, isolation_level=None)
            self._own.execute("PRAGMA busy_timeout = 30000")
        return self._own

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
        """The outbox cursor of a destination as committed, None when it has none."""
        row = self.db.execute("SELECT sample_id FROM outbox WHERE name = ?", (name,)).fetchone()
        return None if row is None else int(row[0])

    def rename_cursor(self, old: str, new: str) -> None:
        """Key a destination's cursor anew (kept if ``new`` has one already);
        with a writer, in its next batch."""
        if self.handoff is None or not self.handoff.put_rename(old, new):
            _rename_on(self.db, old, new)

    def set_cursor(self, name: str, sample_id: int) -> None:
        """Advance the cursor (durably: one small transaction; with a writer,
        in its next batch)."""
        if self.handoff is None or not self.handoff.put_cursor(name, sample_id):
            set_cursor_on(self.db, name, sample_id)

    def state(self, key: str) -> int | None:
        """A remembered integer (the Sparkplug bdSeq): the last one set, also
        while the writer has not committed it yet."""
        if self.handoff is not None:
            unsettled = self.handoff.unsettled_state(key)
            if unsettled is not None:
                return unsettled
        row = self.db.execute("SELECT value FROM fleet_state WHERE key = ?", (key,)).fetchone()
        return None if row is None else int(row[0])

    def set_state(self, key: str, value: int) -> None:
        """Remember an integer durably (with a writer: in its next batch, whose
        commit it asks for and waits for, a few seconds at most)."""
        if self.handoff is None or not self.handoff.put_state(key, value, STATE_COMMIT_WAIT):
            _set_state_on(self.db, key, value)

    # -- the samples ---------------------------------------------------------------

    def durable(self) -> int | None:
        """With a writer, the highest sample id it has committed (ids up to
        it not in the file are gaps); None: all the file has is committed."""
        return self.handoff.committed if self.live and self.handoff is not None else None

    def max_id(self) -> int:
        """The highest sample id (0: none): committed, or with a writer, written."""
        top = max_id(self.db)
        return max(top, self.handoff.written) if self.live and self.handoff else top

    def ids_after(self, sample_id: int) -> set[int]:
        """The ids of the committed samples above ``sample_id``."""
        return {int(i) for (i,) in self.db.execute("SELECT id FROM samples WHERE id > ?",
                                                   (sample_id,))}

    def oldest_after(self, sample_id: int) -> tuple[int, float] | None:
        """(count, time of the oldest) of the samples after an id: those
        committed, plus a writer's not yet committed."""
        count, oldest, top = self.db.execute(
            "SELECT COUNT(*), MIN(time_utc), (SELECT MAX(id) FROM samples) FROM samples "
            "WHERE id > ?", (sample_id,)).fetchone()
        if self.live and self.handoff is not None:
            n, first = self.handoff.uncommitted(max(sample_id, int(top or 0)))
            if first is not None:
                count += n
                oldest = first if oldest is None else oldest
        return None if not count else (int(count), float(oldest))

    def devices(self) -> list[tuple[str, str, int]]:
        """(name, type, address) of every device the file has samples of, once
        each (a map device has a devices row per group), a writer's new ones last."""
        out = [(str(n), str(t), int(a)) for n, t, a in self.db.execute(
            "SELECT name, type, address FROM devices GROUP BY name, type, address "
            "ORDER BY MIN(id)")]
        if self.live and self.handoff is not None:
            out += [d for d in dict.fromkeys((r.name, r.kind, r.address)
                                             for r in self.handoff.devices()) if d not in out]
        return out

    def latest(self, device: str) -> StoredSample | None:
        """The newest sample of a device: a writer's not yet committed, else
        the newest committed."""
        if self.live and self.handoff is not None:
            held = self._decoded(self.handoff.newest(device))
            if held:
                return held[0]
        found = self.db.execute(
            "SELECT MAX(s.id) FROM samples s JOIN devices d ON d.id = s.device_id "
            "WHERE d.name = ?", (device,)).fetchone()[0]
        if found is None:
            return None
        got_ = self.samples_after(int(found) - 1, 1)
        return got_[0] if got_ else None

    def samples_after(self, sample_id: int, limit: int,
                      before: int | None = None) -> list[StoredSample]:
        """The samples with ids above ``sample_id`` (and below ``before``), in
        id order, at most ``limit``: pymb.store's reader of its storage format,
        in one snapshot of what is committed; with a writer, then the samples
        of its open batch that follow."""
        handoff = self.handoff if self.live else None
        committed = 0 if handoff is None else handoff.committed  # before the snapshot
        db = self.db
        db.execute("BEGIN")  # one snapshot for the samples and their values
        try:
            got = stored_after(db, sample_id, limit, before)
        finally:
            db.execute("COMMIT")
        if handoff is not None and len(got) < limit:
            got += self._decoded(handoff.after(got[-1].id if got else sample_id, committed,
                                               limit - len(got), before))
        return got

    def _decoded(self, written: Written) -> list[StoredSample]:
        rows, hubs, devices = written
        decode = self._rows
        for did in {r[1] for r in rows}:
            if not decode.knows(did, devices[did]):
                decode.add(did, devices[did])
        return [decode.sample(r, hubs.get(r[0], ())) for r in rows]


def write_pending(db: sqlite3.Connection, handoff: Handoff, closing: bool = False) -> None:
    """A forwarder's writes handed over (:meth:`Handoff.take_writes`), into
    the writer's open batch of ``db`` (the writer's thread)."""
    renames, cursor, states = handoff.take_writes(closing)
    for old, new in renames:
        _rename_on(db, old, new)
    if cursor is not None:
        set_cursor_on(db, *cursor)
    for key, value in states.items():
        _set_state_on(db, key, value)


def _rename_on(db: sqlite3.Connection, old: str, new: str) -> None:
    db.execute("UPDATE OR IGNORE outbox SET name = ? WHERE name = ?", (new, old))
    db.execute("DELETE FROM outbox WHERE name = ?", (old,))


def _set_state_on(db: sqlite3.Connection, key: str, value: int) -> None:
    db.execute("INSERT OR REPLACE INTO fleet_state VALUES (?, ?)", (key, value))


def set_cursor_on(db: sqlite3.Connection, name: str, sample_id: int) -> None:
    """Advance a destination's cursor through any connection to the file (the
    writer's, inside its batch: :func:`write_pending`);
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
