"""Where the rows go: ``pymb_values`` and the ``pymb_latest`` view, in SQLite
(the embedded default) or PostgreSQL (``postgresql://...``, psycopg 3).

Each :meth:`Store.write` is one transaction, committed before it returns: the
collector acknowledges a batch's messages to the broker only after that. A
row whose (node, device, point, time) is already stored is skipped. Errors
are :class:`StoreDown` (the database cannot be reached now: the collector
holds its messages and tries again) or :class:`StoreRefused` (it refuses the
writes: exit code 5).
"""

from __future__ import annotations

import contextlib
import os
import sqlite3
import time
from collections.abc import Sequence
from typing import Any

from pymb.collect.rows import Row
from pymb.errors import InvalidArgument, ModbusConnectionError, OutputError
from pymb.extras import install_hint

__all__ = ["PG_WRITERS", "PostgresStore", "SqliteStore", "Store", "StoreDown", "StoreRefused",
           "open_store", "open_stores"]

#: connections (writer threads) of a collector into PostgreSQL, which takes
#: several transactions at once; a SQLite file has one writer
PG_WRITERS = 3


class StoreDown(ModbusConnectionError):
    """The database cannot be reached (now)."""


class StoreRefused(OutputError):
    """The database refuses the writes (permissions, a full disk, a read-only file)."""


SQLITE_SCHEMA = """
CREATE TABLE IF NOT EXISTS pymb_values (
    node TEXT NOT NULL, device TEXT NOT NULL, point TEXT NOT NULL, time REAL NOT NULL,
    value REAL, text TEXT, state TEXT, sample INTEGER, received REAL NOT NULL,
    PRIMARY KEY (node, device, point, time));
CREATE INDEX IF NOT EXISTS pymb_values_device_point ON pymb_values (device, point, time);
CREATE VIEW IF NOT EXISTS pymb_latest AS
    SELECT node, device, point, max(time) AS time, value, text, state, sample, received
    FROM pymb_values GROUP BY node, device, point;
"""

PG_TABLE = """
CREATE TABLE IF NOT EXISTS pymb_values (
    node text NOT NULL, device text NOT NULL, point text NOT NULL, time timestamptz NOT NULL,
    value double precision, text text, state text, sample bigint,
    received timestamptz NOT NULL,
    CONSTRAINT pymb_values_key UNIQUE (node, device, point, time))
"""
PG_INDEX = ("CREATE INDEX IF NOT EXISTS pymb_values_device_point "
            "ON pymb_values (device, point, time)")
PG_VIEW = """
CREATE OR REPLACE VIEW pymb_latest AS
    SELECT DISTINCT ON (node, device, point)
           node, device, point, time, value, text, state, sample, received
    FROM pymb_values ORDER BY node, device, point, time DESC
"""
#: the batch's rows go first into this (times as Unix seconds), then into
#: pymb_values in one INSERT that skips what is stored already, in key order:
#: writers inserting the same keys at once wait for each other, never deadlock
PG_INCOMING = """
CREATE TEMP TABLE IF NOT EXISTS pymb_incoming (
    node text, device text, point text, time double precision, value double precision,
    text text, state text, sample bigint) ON COMMIT DELETE ROWS
"""
PG_MOVE = """
INSERT INTO pymb_values (node, device, point, time, value, text, state, sample, received)
SELECT node, device, point, to_timestamp(time), value, text, state, sample, to_timestamp(%s)
FROM pymb_incoming ORDER BY node, device, point, time ON CONFLICT DO NOTHING
"""
#: serialises the schema's creation between collectors starting together
PG_LOCK = 0x70796D62  # "pymb"


class Store:
    """A database the collector writes to."""

    target: str  #: what the user gave (a PostgreSQL URL with any password hidden)
    hypertable = False  #: PostgreSQL with TimescaleDB: pymb_values is a hypertable

    def write(self, rows: Sequence[Row]) -> int:
        """Store ``rows`` in one committed transaction; the number of new rows."""
        raise NotImplementedError

    def close(self) -> None:
        """Close the connection."""


class SqliteStore(Store):
    """A SQLite file (WAL, a commit that survives a power cut: ``synchronous=FULL``)."""

    def __init__(self, path: str) -> None:
        self.target = path
        if os.path.isdir(path):
            raise InvalidArgument(f"{path} is a directory; --out needs a SQLite file or "
                                  "a postgresql:// URL")
        try:
            self.con = sqlite3.connect(path, isolation_level=None, check_same_thread=False,
                                       timeout=30)
            self.con.execute("PRAGMA journal_mode=WAL")
            self.con.execute("PRAGMA synchronous=FULL")
            self.con.execute("PRAGMA cache_size=-65536")  # 64 MiB: the key's B-tree stays in memory
            self.con.executescript(SQLITE_SCHEMA)
        except sqlite3.DatabaseError as e:
            raise InvalidArgument(f"cannot use {path} as the collector's database: "
                                  f"{e}") from None

    def write(self, rows: Sequence[Row]) -> int:
        """One transaction of INSERT OR IGNORE."""
        received = time.time()
        con = self.con
        try:
            before = con.total_changes
            con.execute("BEGIN IMMEDIATE")
            con.executemany("INSERT OR IGNORE INTO pymb_values VALUES (?,?,?,?,?,?,?,?,?)",
                            [(*r, received) for r in rows])
            con.execute("COMMIT")
            return con.total_changes - before
        except sqlite3.Error as e:
            with contextlib.suppress(sqlite3.Error):
                con.execute("ROLLBACK")
            if isinstance(e, sqlite3.OperationalError) and "locked" in str(e):
                raise StoreDown(f"{self.target} is locked by another program") from None
            raise StoreRefused(f"cannot write to {self.target}: {e}") from None

    def close(self) -> None:
        """Close the file."""
        with contextlib.suppress(sqlite3.Error):
            self.con.close()


def _copy_field(v: str | float | int | None) -> str:
    if v is None:
        return "\\N"
    if isinstance(v, str):
        if "\\" in v or "\t" in v or "\n" in v or "\r" in v:
            v = (v.replace("\\", "\\\\").replace("\t", "\\t").replace("\n", "\\n")
                 .replace("\r", "\\r"))
        return v
    return str(v)


def copy_text(rows: Sequence[Row]) -> str:
    """The rows in COPY's text format (tab-separated, ``\\N`` for NULL)."""
    return "".join("\t".join([_copy_field(x) for x in r]) + "\n" for r in rows)


def _hide_password(url: str) -> str:
    from urllib.parse import urlsplit, urlunsplit
    u = urlsplit(url)
    if u.password is None:
        return url
    netloc = u.netloc.replace(f":{u.password}@", ":***@", 1)
    return urlunsplit(u._replace(netloc=netloc))


class PostgresStore(Store):
    """A PostgreSQL database (psycopg 3): each batch is COPYed into a temporary
    table and moved into ``pymb_values`` with ``ON CONFLICT DO NOTHING``, one
    commit per batch. With TimescaleDB installed, ``pymb_values`` is a
    hypertable."""

    def __init__(self, url: str) -> None:
        try:
            import psycopg
        except ImportError:
            raise InvalidArgument(f"a PostgreSQL target needs psycopg: "
                                  f"{install_hint('collect')}") from None
        self.psycopg = psycopg
        self.url = url
        self.target = _hide_password(url)
        self.con: Any = None
        self._connect()

    def _connect(self) -> None:
        psycopg = self.psycopg
        try:
            con = psycopg.connect(self.url, connect_timeout=10, autocommit=False)
        except psycopg.ProgrammingError as e:  # a malformed URL
            raise InvalidArgument(f"bad PostgreSQL URL {self.target}: {e}") from None
        except psycopg.Error as e:
            raise StoreDown(f"cannot connect to {self.target}: {_first_line(e)}") from None
        try:
            with con.cursor() as cur:
                cur.execute("SELECT pg_advisory_xact_lock(%s)", (PG_LOCK,))
                self.hypertable = self._timescale(cur)
                cur.execute(PG_TABLE)
                cur.execute(PG_INDEX)
                if self.hypertable:
                    cur.execute("SELECT create_hypertable('pymb_values', 'time', "
                                "if_not_exists => TRUE, migrate_data => TRUE)")
                cur.execute(PG_VIEW)
                cur.execute(PG_INCOMING)
            con.commit()
        except psycopg.OperationalError as e:
            con.close()
            raise StoreDown(f"{self.target}: {_first_line(e)}") from None
        except psycopg.Error as e:
            con.close()
            raise StoreRefused(f"cannot make the tables in {self.target}: "
                               f"{_first_line(e)}") from None
        self.con = con

    def _timescale(self, cur: Any) -> bool:
        """True when TimescaleDB is (or can be made) an extension of the database."""
        cur.execute("SELECT 1 FROM pg_extension WHERE extname = 'timescaledb'")
        if cur.fetchone():
            return True
        cur.execute("SELECT 1 FROM pg_available_extensions WHERE name = 'timescaledb'")
        if not cur.fetchone():
            return False
        try:
            with cur.connection.transaction():  # a savepoint
                cur.execute("CREATE EXTENSION IF NOT EXISTS timescaledb")
        except self.psycopg.Error:
            return False  # not preloaded, or not ours to create: a plain table
        return True

    def write(self, rows: Sequence[Row]) -> int:
        """COPY into the temporary table, INSERT ... ON CONFLICT DO NOTHING, COMMIT."""
        psycopg = self.psycopg
        if self.con is None or self.con.closed:
            self._connect()
        con = self.con
        try:
            with con.cursor() as cur:
                with cur.copy("COPY pymb_incoming FROM STDIN") as cp:
                    cp.write(copy_text(rows))
                cur.execute(PG_MOVE, (time.time(),))
                n = int(cur.rowcount)
            con.commit()
            return n
        except psycopg.Error as e:
            with contextlib.suppress(psycopg.Error):
                con.close()
            self.con = None
            if isinstance(e, psycopg.OperationalError):
                raise StoreDown(f"{self.target}: {_first_line(e)}") from None
            raise StoreRefused(f"{self.target} refuses the rows: {_first_line(e)}") from None

    def close(self) -> None:
        """Close the connection."""
        if self.con is not None:
            with contextlib.suppress(Exception):
                self.con.close()


def _first_line(e: BaseException) -> str:
    return (str(e).strip().splitlines() or [type(e).__name__])[0]


def is_postgres(target: str) -> bool:
    """True for a ``postgresql://`` (or ``postgres://``) URL."""
    return target.startswith(("postgresql://", "postgres://"))


def open_store(target: str) -> Store:
    """The store ``target`` names: a PostgreSQL URL, else a SQLite file."""
    return PostgresStore(target) if is_postgres(target) else SqliteStore(target)


def open_stores(target: str) -> list[Store]:
    """One store per writer: :data:`PG_WRITERS` connections to PostgreSQL, one
    SQLite file."""
    stores = [open_store(target)]
    try:
        if is_postgres(target):
            stores += [PostgresStore(target) for _ in range(PG_WRITERS - 1)]
    except BaseException:
        for s in stores:
            s.close()
        raise
    return stores
