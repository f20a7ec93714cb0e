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

import abc
import contextlib
import os
import sqlite3
import time
from typing import TYPE_CHECKING, NoReturn

from pymb.collect.pgcopy import COPY_COLUMNS, CopyBatch
from pymb.collect.rows import Batch, RowBatch
from pymb.errors import InvalidArgument, ModbusConnectionError, OutputError
from pymb.extras import install_hint
from pymb.store.guard import sqlite_tables

if TYPE_CHECKING:  # the extra pymb-modbus[collect]
    from psycopg import Connection, Cursor
    from psycopg.rows import TupleRow

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
    received timestamptz NOT NULL DEFAULT now(),
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
#: a batch is COPYed straight into pymb_values (received: the table's default,
#: the transaction's start); a batch that holds a row stored already (a
#: redelivery) goes instead into this, then into pymb_values in one INSERT that
#: skips what is stored. Both take the rows in the order (node, device, time,
#: point), by their bytes: writers inserting the same keys at once wait for
#: each other, never deadlock
PG_INCOMING = """
CREATE TEMP TABLE IF NOT EXISTS pymb_incoming (
    point text, value double precision, node text, device text, time timestamptz,
    sample bigint, text text, state text) ON COMMIT DELETE ROWS
"""
PG_COPY = "COPY {table} ({columns}) FROM STDIN (FORMAT binary)"
PG_MOVE = """
INSERT INTO pymb_values ({columns})
SELECT {columns} FROM pymb_incoming
ORDER BY node COLLATE "C", device COLLATE "C", time, point COLLATE "C" ON CONFLICT DO NOTHING
"""
#: tables made before received had its default get it
PG_RECEIVED = """
SELECT 1 FROM pg_attrdef d JOIN pg_attribute a ON a.attrelid = d.adrelid AND a.attnum = d.adnum
WHERE d.adrelid = 'pymb_values'::regclass AND a.attname = 'received'
"""
#: seconds a writer sends its batches through pymb_incoming after one held a
#: row stored already (redeliveries come in runs)
STAGED_FOR = 30.0
#: a batch that lost a deadlock (two writers, the same rows) is tried again
#: this many times at once
DEADLOCK_TRIES = 5
_COLUMNS = ", ".join(COPY_COLUMNS)
#: serialises the schema's creation between collectors starting together
PG_LOCK = 0x70796D62  # "pymb"


class Store(abc.ABC):
    """A database the collector writes to."""

    target: str  #: what the user gave (a PostgreSQL URL with any password hidden)
    hypertable = False  #: PostgreSQL with TimescaleDB: pymb_values is a hypertable

    @abc.abstractmethod
    def batch(self) -> Batch:
        """An empty batch of the kind :meth:`write` takes."""

    @abc.abstractmethod
    def write(self, batch: Batch) -> int:
        """Store a batch in one committed transaction; the number of new rows."""

    def close(self) -> None:  # noqa: B027 (a hook: nothing to close by default)
        """Close the connection."""


class SqliteStore(Store):
    """A SQLite file (WAL, a commit that survives a power cut: ``synchronous=FULL``)."""

    def __init__(self, path: str) -> None:
        self.target = path
        if path == "-":  # stdout, as the text formats of pymb log take it: no file named '-'
            raise InvalidArgument("--out - : the collector stores into a database, not stdout; "
                                  "give a SQLite file or a postgresql:// URL")
        if os.path.isdir(path):
            raise InvalidArgument(f"{path} is a directory; --out needs a SQLite file or "
                                  "a postgresql:// URL")
        if "://" in path:  # another database's URL (sqlite://, mysql://): not a file name
            raise InvalidArgument(f"{path} is a URL pymb collect does not take; --out needs "
                                  "a SQLite file or a postgresql:// URL")
        folder = os.path.dirname(path) or "."
        if not os.path.isdir(folder):  # a disk not mounted yet: not a usage error (exit 4)
            raise StoreDown(f"cannot open {path}: its folder {folder} does not exist; create "
                            "it, or mount the disk that holds it")
        tables = sqlite_tables(path) if os.path.isfile(path) else None
        if tables and "pymb_values" not in tables:  # pymb log's database, another program's
            raise InvalidArgument(f"{path} is a SQLite database pymb collect did not write: "
                                  "refusing to add to it; choose another --out")
        try:
            self.con = sqlite3.connect(path, isolation_level=None, check_same_thread=False,
                                       timeout=30)
        except sqlite3.DatabaseError as e:
            raise InvalidArgument(f"cannot use {path} as the collector's database: "
                                  f"{e}") from None
        try:
            self.con.execute("PRAGMA journal_mode=WAL")
            self.con.execute("PRAGMA synchronous=FULL")
            self.con.execute("PRAGMA cache_size=-65536")  # 64 MiB: the key's B-tree stays in memory
            self.con.executescript(SQLITE_SCHEMA)
        except sqlite3.DatabaseError as e:
            self.close()
            if isinstance(e, sqlite3.OperationalError) and "locked" in str(e):
                # another program holds it and may let go: not a usage error (exit 4)
                raise StoreDown(f"{path} is locked by another program") from None
            raise InvalidArgument(f"cannot use {path} as the collector's database: "
                                  f"{e}") from None

    def batch(self) -> RowBatch:
        """Rows as tuples (SQLite binds them one by one)."""
        return RowBatch()

    def write(self, batch: Batch) -> int:
        """One transaction of INSERT OR IGNORE."""
        assert isinstance(batch, RowBatch)
        rows = batch.items
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


def _hide_password(url: str) -> str:
    from urllib.parse import urlsplit, urlunsplit
    try:
        u = urlsplit(url)
    except ValueError as e:  # "Invalid IPv6 URL": said without the URL (its password)
        raise InvalidArgument(f"bad PostgreSQL URL: {e}") from None
    if u.password is None:
        return url
    netloc = u.netloc.replace(f":{u.password}@", ":***@", 1)
    return urlunsplit(u._replace(netloc=netloc))


class PostgresStore(Store):
    """A PostgreSQL database (psycopg 3): each batch is one binary COPY into
    ``pymb_values`` and one commit; a batch holding a row stored already goes
    through a temporary table and ``INSERT ... ON CONFLICT DO NOTHING`` (and so
    do the batches of the next :data:`STAGED_FOR` seconds). With TimescaleDB
    installed, ``pymb_values`` is a hypertable."""

    def __init__(self, url: str) -> None:
        try:
            import psycopg
        except ImportError:
            raise InvalidArgument(f"a PostgreSQL target needs psycopg: "
                                  f"{install_hint('collect')}") from None
        self.psycopg = psycopg
        self.url = url
        self.target = _hide_password(url)
        self.con: Connection[TupleRow] | None = None
        self._staged_until = 0.0  #: monotonic time until which batches go through pymb_incoming
        self._caches: CopyBatch | None = None
        self._connect()

    def _connect(self) -> Connection[TupleRow]:
        psycopg = self.psycopg
        try:
            ports = str(psycopg.conninfo.conninfo_to_dict(self.url).get("port") or "")
        except psycopg.ProgrammingError as e:  # a malformed URL
            raise InvalidArgument(f"bad PostgreSQL URL {self.target}: {e}") from None
        if ports and not all(p.isdigit() and 1 <= int(p) <= 65535 for p in ports.split(",")):
            raise InvalidArgument(f"bad PostgreSQL URL {self.target}: the port must be "
                                  f"1..65535, got {ports}")
        con: Connection[TupleRow]
        try:
            con = psycopg.connect(self.url, connect_timeout=10, autocommit=False,
                                  client_encoding="UTF8")
        except psycopg.ProgrammingError as e:  # a malformed URL
            raise InvalidArgument(f"bad PostgreSQL URL {self.target}: {e}") from None
        except psycopg.Error as e:
            raise StoreDown(f"cannot connect to {self.target}: {_first_line(e)}") from None
        try:
            with con.cursor() as cur:
                cur.execute("SELECT pg_advisory_xact_lock(%s)", (PG_LOCK,))
                self.hypertable = self._timescale(cur)
                cur.execute(PG_TABLE)
                if not cur.execute(PG_RECEIVED).fetchone():
                    cur.execute("ALTER TABLE pymb_values ALTER COLUMN received SET DEFAULT now()")
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
        return con

    def _timescale(self, cur: Cursor[TupleRow]) -> bool:
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

    def batch(self) -> CopyBatch:
        """Rows in COPY's binary format (the formats of messages made once)."""
        b = CopyBatch()
        if self._caches is not None:
            b.adopt(self._caches)
        self._caches = b
        return b

    def write(self, batch: Batch) -> int:
        """One binary COPY and a commit; through pymb_incoming when a row is
        stored already."""
        assert isinstance(batch, CopyBatch)
        psycopg = self.psycopg
        con = self.con
        if con is None or con.closed:
            con = self._connect()
        data = batch.data()
        lost = 0
        while True:
            staged = time.monotonic() < self._staged_until
            try:
                return self._copy(con, data, staged)
            except (psycopg.errors.UniqueViolation, psycopg.errors.TransactionRollback) as e:
                # a row stored already, or a deadlock with a writer storing the same
                # rows: once more through pymb_incoming, in key order
                with contextlib.suppress(psycopg.Error):
                    con.rollback()
                self._staged_until = time.monotonic() + STAGED_FOR
                if isinstance(e, psycopg.errors.TransactionRollback):
                    lost += 1
                    if lost < DEADLOCK_TRIES:
                        continue
                elif not staged:
                    continue
                self._failed(e)
            except psycopg.Error as e:
                self._failed(e)

    def _copy(self, con: Connection[TupleRow], data: bytes, staged: bool) -> int:
        with con.cursor() as cur:
            with cur.copy(PG_COPY.format(table="pymb_incoming" if staged else "pymb_values",
                                         columns=_COLUMNS)) as cp:
                cp.write(data)
            n = cur.rowcount
            if staged:
                cur.execute(PG_MOVE.format(columns=_COLUMNS))
                n = cur.rowcount
        con.commit()
        return int(n)

    def _failed(self, e: BaseException) -> NoReturn:
        """Close the connection (the next write opens another) and raise
        StoreDown (it cannot be reached) or StoreRefused."""
        if self.con is not None:
            with contextlib.suppress(self.psycopg.Error):
                self.con.close()
        self.con = None
        if isinstance(e, self.psycopg.OperationalError):
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
