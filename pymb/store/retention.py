"""Retention: the size and age limits of a database (deleting the oldest
samples and events, and giving pages back), and the event that says when
samples not yet forwarded go."""

from __future__ import annotations

import contextlib
import math
import os
import re
import sqlite3
import time
from collections.abc import Callable
from pathlib import Path

from pymb.store.faults import is_storage_fault
from pymb.store.schema import SqlArg

__all__ = ["PLAUSIBLE", "RESTAMP_TOLERANCE", "Restamp", "Retention", "clock_plausible"]

#: 2025-01-01 00:00:00 UTC: a wall clock earlier than this has not been set (a
#: board without a real-time clock boots in 1970); samples stamped before it were
#: taken before the clock was set, and their age is unknown
PLAUSIBLE = 1735689600.0
#: bytes of the disk left free under a size limit the disk cannot hold (the
#: -shm index, the journal of the file system)
DISK_MARGIN = 1 << 20
#: seconds a stamp may differ from its monotonic time plus the clock's offset and
#: still be of the same clock (a larger change of the offset is a step)
RESTAMP_TOLERANCE = 1.0


def clock_plausible(now: float | None = None) -> bool:
    """True when the wall clock (or ``now``) is not before :data:`PLAUSIBLE`."""
    return (time.time() if now is None else now) >= PLAUSIBLE

class Restamp:
    """A pending re-stamping of a run after a clock step: the new offset, the
    next id and the last id to look at in ``samples`` and ``events``."""

    def __init__(self, offset: float, first: list[int], top: list[int]) -> None:
        self.offset = offset
        self.next = first
        self.top = top
        self._row_bytes: float | None = None

    def rows(self, db: sqlite3.Connection, budget: int) -> int:
        """Rows a step may re-stamp: about ``budget`` bytes of rows."""
        if self._row_bytes is None:
            (avg,) = db.execute("SELECT AVG(LENGTH(registers)) FROM (SELECT registers FROM "
                                "samples WHERE id >= ? LIMIT 64)", (self.next[0],)).fetchone()
            self._row_bytes = float(avg or 0) + 64  # the row's other columns, its index entry
        return max(16, int(budget / self._row_bytes))

    def step(self, db: sqlite3.Connection, budget: int) -> bool:
        """Re-stamp the next rows (about ``budget`` bytes of them) in the
        open transaction of ``db``; True once every row was looked at."""
        rows = self.rows(db, budget)
        for i, table in enumerate(("samples", "events")):
            lo, hi = self.next[i], min(self.next[i] + rows, self.top[i] + 1)
            if lo >= hi:
                continue
            args = {"off": self.offset, "tol": RESTAMP_TOLERANCE, "lo": lo, "hi": hi}
            db.execute(f"UPDATE {table} SET time_utc = monotonic + :off WHERE id >= :lo "
                       "AND id < :hi AND ABS(time_utc - monotonic - :off) > :tol", args)
            if table == "samples" and db.execute("SELECT 1 FROM hub_changes LIMIT 1").fetchone():
                db.execute("UPDATE hub_changes SET time_utc = (SELECT time_utc FROM samples "
                           "WHERE id = sample_id) WHERE sample_id >= :lo AND sample_id < :hi "
                           "AND time_utc != (SELECT time_utc FROM samples WHERE id = sample_id)",
                           args)
            self.next[i] = hi
        return all(n > t for n, t in zip(self.next, self.top, strict=True))


_TRIM_IDS = re.compile(r"\(ids (\d+)\.\.(\d+)\)$")


class Retention:
    """The size and age limits of one SQLite writer
    (:class:`pymb.store.writer.SqliteSink` owns one): what the database may
    hold, and the trimming that holds it. ``page_size`` and ``wal_budget`` are
    the file's, as :func:`pymb.store.schema.open_format` set them."""

    def __init__(self, db: sqlite3.Connection, path: Path, *, max_bytes: int | None,
                 max_age: float | None, page_size: int, wal_budget: int) -> None:
        self.db = db
        self.max_bytes = max_bytes
        self.max_age = max_age
        self.page_size = page_size
        self.wal_budget = wal_budget
        self.trimmed = 0  #: samples deleted by the size and age limits so far
        #: trim in small steps, each checkpointed (a full disk: little room for the WAL)
        self.small_steps = False
        self._wal = Path(f"{path}-wal")
        #: the file keeps pointer-map pages (``auto_vacuum = INCREMENTAL``): it
        #: shrinks a little at a time; pymb's new files have none (a page less
        #: rewritten by every commit) and shrink by one VACUUM
        self._incremental = int(db.execute("PRAGMA auto_vacuum").fetchone()[0]) == 2
        self._last_age_trim = time.monotonic()

    def over_room(self) -> bool:
        """Under a size limit, the pages in use take more than :meth:`room`."""
        count, free = self.pages()
        return (count - free) * self.page_size > self.room()

    def trim_at_open(self, give_up_reserve: Callable[[], bool]) -> None:
        """Within the size limit before the first sample (a lower limit than
        last time, or a database that filled its disk). On a full disk
        ``give_up_reserve`` frees the reserve's room (False: none left) and
        the trim runs in small steps with a checkpoint after each (a short WAL)."""
        if self.over_room():
            try:
                self.trim()
            except sqlite3.Error as e:
                if not is_storage_fault(e) or not give_up_reserve():
                    raise
                self.small_steps = True
                try:
                    self.checkpoint()
                    self.trim()
                finally:
                    self.small_steps = False
        self.give_back(vacuum=True)

    def age_due(self) -> bool:
        """Under an age limit, the last age trim was 5 s ago or more."""
        return self.max_age is not None and time.monotonic() - self._last_age_trim >= 5.0

    def room(self) -> int:
        """Bytes the database's pages may take: the limit less the WAL (its
        budget, or what it holds now if more). A limit above what the disk
        can hold is the disk's: the file as it is plus the free space, less
        room for the WAL to reach its budget (the file's free pages are
        reused rather than the disk filled)."""
        assert self.max_bytes is not None
        wal = self.wal_bytes()
        limit = self.max_bytes
        try:
            st = os.statvfs(self._wal.parent)
            size = self._wal.with_name(self._wal.name[:-4]).stat().st_size
        except OSError:
            pass  # the next write says what is wrong
        else:
            disk = size + wal + st.f_bavail * st.f_frsize - self.wal_budget - DISK_MARGIN
            limit = min(limit, max(disk, size))
        return limit - max(self.wal_budget, wal)

    def checkpoint(self) -> None:
        """Copy the WAL into the database and truncate it, unless a reader
        still needs it (then next time; never wait for a reader)."""
        self.db.execute("PRAGMA busy_timeout = 0")
        try:
            self.db.execute("PRAGMA wal_checkpoint(TRUNCATE)").fetchone()
        finally:
            self.db.execute("PRAGMA busy_timeout = 5000")

    def wal_bytes(self) -> int:
        try:
            return self._wal.stat().st_size
        except OSError:
            return 0

    def pages(self) -> tuple[int, int]:
        count = self.db.execute("PRAGMA page_count").fetchone()[0]
        free = self.db.execute("PRAGMA freelist_count").fetchone()[0]
        return int(count), int(free)

    def size(self) -> int:
        """Bytes the data takes: pages in use plus the WAL."""
        count, free = self.pages()
        return (count - free) * self.page_size + self.wal_bytes()

    def trim(self) -> int:
        deleted = 0
        if self.max_age is not None:
            self._last_age_trim = time.monotonic()
        if self.max_age is not None and clock_plausible():
            # Only with a clock that was set; and never a sample a forwarder has not
            # sent: its age is what a clock says, which may have been wrong when it
            # was stamped or be wrong now (a board's saved date, a step); samples
            # stamped before a clock was set (their age unknown) go once sent.
            cutoff = time.time() - self.max_age
            deleted += self._delete_before(
                "SELECT COALESCE(MIN(id), 0) FROM samples WHERE time_utc >= ? OR id > ?",
                (cutoff, self._lowest_cursor()), cutoff)
        if self.max_bytes is not None:
            # Delete down to 95 % of the room left beside the WAL, so the freed
            # pages take the next inserts and the file stops growing.
            room = self.room()
            for _ in range(64):
                count, free = self.pages()
                used = (count - free) * self.page_size
                if used <= room:
                    break
                lo, hi = self.db.execute("SELECT MIN(id), MAX(id) FROM samples").fetchone()
                if lo is not None and lo < hi:
                    share = min(0.02 if self.small_steps else 0.5, (used - 0.95 * room) / used)
                    step = max(1, int((hi - lo) * share))
                    deleted += self._delete_before("SELECT ?", (lo + step,), None)
                    if self.small_steps:
                        self.checkpoint()
                elif not self._delete_oldest_events():
                    break  # nothing left that may go
            self.give_back()
        self.trimmed += deleted
        return deleted

    def give_back(self, vacuum: bool = False) -> None:
        """A file larger than the size limit allows (a lower limit than last
        time) gives its free pages back, towards the limit less the WAL's
        budget: a file with incremental
        vacuum a little at a time; a file without it (as pymb makes them: no
        pointer-map page for every commit to rewrite) only at open
        (``vacuum``), by one VACUUM when the disk holds the copy it makes (the
        pages in use, twice: its temporary database and the WAL; a VACUUM
        that finds no room for its copy leaves the file as it was). While
        logging such a file reuses its free pages and grows no more: a VACUUM
        then would put a copy of the whole file in the WAL, past the limit."""
        assert self.max_bytes is not None
        count, free = self.pages()
        fixed = self.max_bytes - self.wal_budget
        if count * self.page_size <= 1.05 * fixed or not free:
            return
        if self._incremental:
            chunk = max(1, self.wal_budget // (64 if self.small_steps else 4)
                        // self.page_size)
            while free > 0 and count * self.page_size > fixed:
                self.db.execute(f"PRAGMA incremental_vacuum({chunk})").fetchall()
                self.checkpoint()
                count, free = self.pages()
            return
        if not vacuum:
            return
        need = 2 * (count - free) * self.page_size + DISK_MARGIN
        try:
            st = os.statvfs(self._wal.parent)
        except OSError:
            return  # the next write says what is wrong
        if st.f_bavail * st.f_frsize < need:
            return
        self.checkpoint()
        try:
            self.db.execute("VACUUM")
        except sqlite3.Error as e:
            # The copy is made in SQLite's temporary directory, which may be
            # another disk than the database's (a small tmpfs /tmp): without
            # room there the file keeps its size, as without room here.
            if not is_storage_fault(e):
                raise
            return
        self.checkpoint()

    def _delete_oldest_events(self) -> int:
        """A long outage logs events and no samples: they must go too."""
        lo, hi = self.db.execute("SELECT MIN(id), MAX(id) FROM events").fetchone()
        if lo is None or lo >= hi:
            return 0
        self.db.execute("BEGIN IMMEDIATE")
        try:
            # The records of unsent samples deleted go last of all, and the
            # newest of them never (it counts every outage before it).
            below = lo + max(1, (hi - lo) // 10)
            n = self.db.execute("DELETE FROM events WHERE id < ? AND kind != 'trim'",
                                (below,)).rowcount
            if not n:
                n = self.db.execute(
                    "DELETE FROM events WHERE id < ? AND id < (SELECT MAX(id) FROM events "
                    "WHERE kind = 'trim')", (below,)).rowcount
            self.db.execute("COMMIT")
        except BaseException:
            self._rollback()
            raise
        return int(n)

    def _rollback(self) -> None:
        """Roll back what failed, if SQLite has not already (a full disk
        rolls back by itself; a second ROLLBACK would hide why)."""
        if self.db.in_transaction:
            with contextlib.suppress(sqlite3.Error):
                self.db.execute("ROLLBACK")

    def _delete_before(self, find: str, args: tuple[SqlArg, ...], cutoff: float | None) -> int:
        (first_kept,) = self.db.execute(find, args).fetchone()
        if first_kept == 0:  # nothing young enough: all but the newest go; the newest
            # stays so that SQLite never hands out its id (or lower ones) again: sample
            # ids are unique and increasing for the MQTT forwarder and its consumers
            first_kept = self.db.execute("SELECT MAX(id) FROM samples").fetchone()[0] or 1
        self.db.execute("BEGIN IMMEDIATE")
        try:
            self._unsent_event(first_kept)
            kept_time = self.db.execute("SELECT time_utc FROM samples WHERE id >= ? "
                                        "ORDER BY id LIMIT 1", (first_kept,)).fetchone()
            limit = cutoff if cutoff is not None else (
                kept_time[0] if kept_time else math.inf)
            on_change = self.db.execute("SELECT 1 FROM hub_changes LIMIT 1").fetchone()
            for did, ch in self.db.execute(  # the devices stored by channel
                    "SELECT device_id, channel FROM channels").fetchall() if on_change else ():
                self.db.execute("DELETE FROM hub_changes WHERE device_id = ? AND channel = ? "
                                "AND time_utc < ? AND sample_id < ?",
                                (did, ch, limit, first_kept))
            n = self.db.execute("DELETE FROM samples WHERE id < ?", (first_kept,)).rowcount
            # The events of the time deleted go too, but not the records of
            # unsent samples deleted (this trim's and earlier ones).
            if cutoff is not None:
                self.db.execute("DELETE FROM events WHERE time_utc < ? AND kind != 'trim'",
                                (cutoff,))
            else:
                self.db.execute(
                    "DELETE FROM events WHERE time_utc < (SELECT COALESCE(MIN(time_utc), 0) "
                    "FROM samples) AND kind != 'trim'")
            self.db.execute("COMMIT")
        except BaseException:
            self._rollback()
            raise
        return int(n)

    def _lowest_cursor(self) -> float:
        """The lowest outbox cursor (every sample up to it was forwarded): 0 for a
        forwarder that has not sent anything yet; infinity when no forwarder ever
        used the database."""
        if not self.db.execute("SELECT 1 FROM sqlite_master WHERE name = 'outbox'").fetchone():
            return math.inf
        (low,) = self.db.execute("SELECT MIN(sample_id) FROM outbox").fetchone()
        return 0.0 if low is None else float(low)

    def _unsent_event(self, first_kept: int) -> None:
        """Never delete samples not yet forwarded (pymb.fleet's ``outbox``
        cursors) silently: an event says how many go. A forwarder that never
        reached its broker has no cursor yet (its table is there): every
        sample is unsent."""
        if not self.db.execute("SELECT 1 FROM sqlite_master WHERE name = 'outbox'").fetchone():
            return
        (low,) = self.db.execute("SELECT COALESCE(MIN(sample_id), 0) FROM outbox").fetchone()
        n, first, last = self.db.execute(
            "SELECT COUNT(*), MIN(id), MAX(id) FROM samples WHERE id > ? AND id < ?",
            (low, first_kept)).fetchone()
        if not n:
            return
        # One record per outage: a trim that goes on where the last one ended
        # (the cursor still below it) adds to its event rather than a new one.
        prev = self.db.execute("SELECT id, code, message FROM events WHERE kind = 'trim' "
                               "ORDER BY id DESC LIMIT 1").fetchone()
        span = None if prev is None else _TRIM_IDS.search(prev[2])
        if span is not None and low < int(span[1]) and int(span[2]) < first:
            n, first = n + int(prev[1] or 0), int(span[1])
            self.db.execute("DELETE FROM events WHERE id = ?", (prev[0],))
        self.db.execute(
            "INSERT INTO events(time_utc, monotonic, bus, device_id, kind, code, message) "
            "VALUES (?, ?, NULL, NULL, 'trim', ?, ?)",
            (time.time(), time.monotonic(), n,
             f"the size/age limit deleted {n} samples not yet forwarded to the MQTT "
             f"broker (ids {first}..{last})"))
