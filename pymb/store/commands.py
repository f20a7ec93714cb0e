"""The record of writes in a logged database: every command the logger
received (its id and result, for once-per-id), one row per point of each
(the ``writes`` view), and the writes counted against write budgets.

The tables are made the first time a logger accepts commands; retention
(``--max-mb``, ``--max-age-days``) deletes samples and events only, never
these: a command id is kept for :data:`KEEP_DAYS` days, then forgotten.
"""

from __future__ import annotations

import csv
import json
import sqlite3
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import IO, Protocol, TypeVar

__all__ = ["KEEP_DAYS", "WRITE_COLUMNS", "CommandLog", "PointRow", "ensure", "export_writes",
           "write_counts"]

#: the columns of the writes view (and of ``pymb export --writes``)
WRITE_COLUMNS = ("time", "source", "command_id", "device", "point", "requested", "before",
                 "after", "ok", "reason")

KEEP_DAYS = 30  #: days a command id (and its result) is kept; the contract asks for 7

_SCHEMA = """
CREATE TABLE IF NOT EXISTS write_commands (
    command_id TEXT PRIMARY KEY,      -- the sender's id: executed once ever
    device TEXT NOT NULL,
    source TEXT NOT NULL,             -- mqtt | sparkplug
    time_utc REAL NOT NULL,           -- when it arrived
    result TEXT                       -- the published result (JSON), NULL while not yet known
);
CREATE TABLE IF NOT EXISTS write_points (
    id INTEGER PRIMARY KEY,
    time_utc REAL NOT NULL,
    source TEXT NOT NULL,
    command_id TEXT,
    device TEXT NOT NULL,
    point TEXT NOT NULL,
    requested TEXT,
    before TEXT,
    after TEXT,
    ok INTEGER NOT NULL,
    reason TEXT
);
CREATE TABLE IF NOT EXISTS write_budget (
    key TEXT NOT NULL,                -- TYPE:ADDRESS/POINT
    time_utc REAL NOT NULL
);
CREATE INDEX IF NOT EXISTS write_budget_key ON write_budget(key, time_utc);
CREATE VIEW IF NOT EXISTS writes AS
    SELECT strftime('%Y-%m-%dT%H:%M:%fZ', time_utc, 'unixepoch') AS time, source, command_id,
           device, point, requested, before, after, ok, reason
    FROM write_points ORDER BY id;
"""


def ensure(db: sqlite3.Connection) -> None:
    """Make the tables and the ``writes`` view where they are missing."""
    for statement in _SCHEMA.split(";"):
        if statement.strip():
            db.execute(statement)


def write_counts(db: sqlite3.Connection) -> tuple[int, int]:
    """(points written and applied, points refused or failed) in ``db``; (0, 0)
    when it never took a command."""
    try:
        row = db.execute("SELECT COALESCE(SUM(ok), 0), COALESCE(SUM(1 - ok), 0) "
                         "FROM write_points").fetchone()
    except sqlite3.OperationalError:  # no such table: no writes
        return 0, 0
    return int(row[0]), int(row[1])


def export_writes(path: str, out: IO[str], *, since: float | None = None,
                  until: float | None = None) -> int:
    """The ``writes`` view of the database at ``path`` as CSV on ``out``
    (a header, then a row per point of each command); returns the rows."""
    w = csv.writer(out, lineterminator="\n")
    w.writerow(WRITE_COLUMNS)
    db = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    try:
        try:
            rows = db.execute(
                "SELECT strftime('%Y-%m-%dT%H:%M:%fZ', time_utc, 'unixepoch'), source, "
                "command_id, device, point, requested, before, after, ok, reason "
                "FROM write_points WHERE time_utc >= ? AND time_utc < ? ORDER BY id",
                (-1e18 if since is None else since, 1e18 if until is None else until))
        except sqlite3.OperationalError:  # no such table: never took a command
            return 0
        n = 0
        for row in rows:
            w.writerow(["" if v is None else v for v in row])
            n += 1
        return n
    finally:
        db.close()


def _text(v: object) -> str | None:
    return None if v is None else json.dumps(v, ensure_ascii=False)


@dataclass
class PointRow:
    """One point of a command, as the ``writes`` view shows it."""

    point: str
    requested: object
    before: object = None
    after: object = None
    ok: bool = False
    reason: str | None = None


T = TypeVar("T")


class InBatch(Protocol):
    """How the record reaches the file: ``run(fn, commit)`` returns
    ``fn(db)`` run inside the writer's batch (:meth:`pymb.store.SqliteSink.in_batch`)."""

    def __call__(self, fn: Callable[[sqlite3.Connection], T], commit: bool, /) -> T:
        """``fn(db)`` in the batch, committed after it when ``commit``."""
        ...


class CommandLog:
    """The record, on the logger's own connection: ``run(fn, commit)`` runs
    ``fn(db)`` inside the writer's batch (under its lock) and commits the
    batch when ``commit`` is true."""

    def __init__(self, run: InBatch,
                 clock: Callable[[], float] = time.time) -> None:
        self._run = run
        self._clock = clock
        run(self._open, True)

    def _open(self, db: sqlite3.Connection) -> None:
        ensure(db)
        cutoff = self._clock() - KEEP_DAYS * 86400
        db.execute("DELETE FROM write_commands WHERE time_utc < ?", (cutoff,))
        db.execute("DELETE FROM write_budget WHERE time_utc < ?", (self._clock() - 7200,))

    def seen(self, command_id: str) -> tuple[bool, str | None]:
        """(whether the id was received before, its stored result or None)."""
        def get(db: sqlite3.Connection) -> tuple[bool, str | None]:
            row = db.execute("SELECT result FROM write_commands WHERE command_id = ?",
                             (command_id,)).fetchone()
            return (False, None) if row is None else (True, row[0])
        got: tuple[bool, str | None] = self._run(get, False)
        return got

    def receive(self, command_id: str, device: str, source: str, *, durable: bool) -> None:
        """Put the command on record (committed when ``durable``: before its write)."""
        now = self._clock()
        self._run(lambda db: db.execute(
            "INSERT OR IGNORE INTO write_commands(command_id, device, source, time_utc) "
            "VALUES (?, ?, ?, ?)", (command_id, device, source, now)), durable)

    def finish(self, command_id: str | None, device: str, source: str, result: str | None,
               rows: Sequence[PointRow], *, durable: bool = True) -> None:
        """The command's result and its points."""
        now = self._clock()

        def put(db: sqlite3.Connection) -> None:
            if command_id is not None and result is not None:
                db.execute("UPDATE write_commands SET result = ? WHERE command_id = ?",
                           (result, command_id))
            db.executemany(
                "INSERT INTO write_points(time_utc, source, command_id, device, point, "
                "requested, before, after, ok, reason) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                [(now, source, command_id, device, r.point, _text(r.requested),
                  _text(r.before), _text(r.after), int(r.ok), r.reason) for r in rows])
        self._run(put, durable)

    def spent(self, key: str, limit: int) -> bool:
        """Whether ``key`` was written ``limit`` times in the last hour."""
        since = self._clock() - 3600
        n = self._run(lambda db: db.execute(
            "SELECT COUNT(*) FROM write_budget WHERE key = ? AND time_utc > ?",
            (key, since)).fetchone()[0], False)
        return int(n) >= limit

    def count(self, key: str) -> None:
        """One write of ``key``, now (committed with the batch)."""
        now = self._clock()
        self._run(lambda db: db.execute(
            "INSERT INTO write_budget(key, time_utc) VALUES (?, ?)", (key, now)), False)
