"""Where logged data goes: SQLite (the default), CSV, JSON Lines.

SQLite: WAL journal, ``synchronous=NORMAL``, commits in batches. A
transaction that committed survives the process being killed (even SIGKILL);
what was not yet committed, at most one batch, is lost. Raw registers are
stored losslessly (a BLOB of big-endian 16-bit words, as on the wire, from
the device map's first register), and decoded values in plain tables and
views that ``sqlite3`` queries directly::

    SELECT time, device, channel, temperature_c FROM hub_readings
     WHERE channel = 3 ORDER BY time DESC LIMIT 10;
"""

from __future__ import annotations

import contextlib
import csv
import json
import math
import os
import sqlite3
import sys
import time
from array import array
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from itertools import repeat
from pathlib import Path
from typing import IO, Any, Protocol

from pymb import __version__
from pymb.devices import HUB, CoolProTelemetry, HubReading, State
from pymb.devices.maps import COOLPRO
from pymb.errors import InvalidArgument

__all__ = [
    "CsvSink",
    "DeviceInfo",
    "Event",
    "JsonlSink",
    "OutputError",
    "Sample",
    "Sink",
    "SqliteSink",
    "open_sink",
]

SCHEMA_VERSION = 1
_COOLPRO_FIELDS = [r.name for r in COOLPRO.group("telemetry")]
_HUB_FIELDS = [b.name for b in HUB.blocks]


class OutputError(Exception):
    """Logged data could not be written (disk full, read-only database or
    file, I/O error). What was committed before is intact; the batch being
    written when it happened is lost."""


@dataclass(frozen=True)
class DeviceInfo:
    """A logged device: its bus, port, type (``coolpro``/``hub``), address, name."""

    bus: str
    port: str
    type: str
    address: int
    name: str


@dataclass(frozen=True)
class Sample:
    """One reading of one device, time-stamped when it completed."""

    device: DeviceInfo
    time_utc: float
    monotonic: float
    data: CoolProTelemetry | HubReading


@dataclass(frozen=True)
class Event:
    """Something that happened instead of (or besides) a sample: a timeout,
    an exception code, a busy hub, an unplugged port, a reconnect."""

    time_utc: float
    monotonic: float
    bus: str
    device: DeviceInfo | None
    kind: str  #: timeout, protocol, exception, busy, connection, reconnect, ...
    code: int | None
    message: str


def _wire_bytes(regs: array[int]) -> bytes:
    out = array("H", regs)
    if sys.byteorder == "little":
        out.byteswap()
    return out.tobytes()


def _finite(v: float) -> float | None:
    return None if math.isnan(v) else v


class Sink(Protocol):
    """What the logger writes to."""

    def write(self, sample: Sample) -> None:
        """Add a sample to the current batch."""

    def event(self, event: Event) -> None:
        """Add an event to the current batch."""

    def commit(self) -> None:
        """Make the batch durable."""

    def close(self) -> None:
        """Commit and release the output."""


# -- SQLite ---------------------------------------------------------------------------

_SCHEMA = f"""
CREATE TABLE IF NOT EXISTS meta(key TEXT PRIMARY KEY, value TEXT);
CREATE TABLE IF NOT EXISTS devices(
    id INTEGER PRIMARY KEY, bus TEXT NOT NULL, port TEXT NOT NULL, type TEXT NOT NULL,
    address INTEGER NOT NULL, name TEXT NOT NULL, UNIQUE(bus, address, type));
CREATE TABLE IF NOT EXISTS samples(
    id INTEGER PRIMARY KEY, device_id INTEGER NOT NULL REFERENCES devices(id),
    time_utc REAL NOT NULL, monotonic REAL NOT NULL,
    registers BLOB NOT NULL  -- big-endian 16-bit words, from the map's first register
);
CREATE INDEX IF NOT EXISTS samples_time ON samples(time_utc);
CREATE TABLE IF NOT EXISTS coolpro(
    sample_id INTEGER PRIMARY KEY REFERENCES samples(id),
    {", ".join(f"{n} {'INTEGER' if n in ('uptime_s', 'status') else 'REAL'}"
               for n in _COOLPRO_FIELDS)});
CREATE TABLE IF NOT EXISTS hub(
    sample_id INTEGER NOT NULL REFERENCES samples(id), channel INTEGER NOT NULL,
    {", ".join(f"{n} REAL" for n in _HUB_FIELDS)},
    {", ".join(f"{n}_state INTEGER" for n in _HUB_FIELDS)},
    PRIMARY KEY(sample_id, channel)) WITHOUT ROWID;
CREATE TABLE IF NOT EXISTS states(code INTEGER PRIMARY KEY, name TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS events(
    id INTEGER PRIMARY KEY, time_utc REAL NOT NULL, monotonic REAL NOT NULL, bus TEXT,
    device_id INTEGER REFERENCES devices(id), kind TEXT NOT NULL, code INTEGER,
    message TEXT NOT NULL);
CREATE INDEX IF NOT EXISTS events_time ON events(time_utc);
-- Views are recreated on every open, so a file written by an older pymb gets
-- the current ones (UTC times with milliseconds; no 'subsec', which needs
-- SQLite 3.42 while Debian 12 has 3.40).
DROP VIEW IF EXISTS coolpro_readings;
DROP VIEW IF EXISTS hub_readings;
DROP VIEW IF EXISTS event_log;
CREATE VIEW coolpro_readings AS
    SELECT strftime('%Y-%m-%d %H:%M:%f', s.time_utc, 'unixepoch') AS time, s.time_utc,
           d.name AS device,
           d.address, c.*
      FROM coolpro c JOIN samples s ON s.id = c.sample_id JOIN devices d ON d.id = s.device_id;
CREATE VIEW hub_readings AS
    SELECT strftime('%Y-%m-%d %H:%M:%f', s.time_utc, 'unixepoch') AS time, s.time_utc,
           d.name AS device,
           d.address, h.*
      FROM hub h JOIN samples s ON s.id = h.sample_id JOIN devices d ON d.id = s.device_id;
CREATE VIEW event_log AS
    SELECT strftime('%Y-%m-%d %H:%M:%f', e.time_utc, 'unixepoch') AS time, e.bus, d.name AS device,
           e.kind, e.code, e.message
      FROM events e LEFT JOIN devices d ON d.id = e.device_id;
"""


class SqliteSink:
    """Writes samples and events to a SQLite database (created if missing).

    ``max_bytes`` / ``max_age`` (seconds) bound the database: the oldest
    samples and events are deleted (and their pages reused) when it grows
    past the size or the data gets older than the age.
    """

    def __init__(self, path: str | os.PathLike[str], *, max_bytes: int | None = None,
                 max_age: float | None = None) -> None:
        self.path = Path(path)
        self.max_bytes = max_bytes
        self.max_age = max_age
        try:
            self.db = sqlite3.connect(self.path, isolation_level=None, check_same_thread=False)
            self.db.execute("PRAGMA auto_vacuum = INCREMENTAL")
            mode = self.db.execute("PRAGMA journal_mode = WAL").fetchone()[0]
            self.db.execute("PRAGMA synchronous = NORMAL")
            self.db.executescript(_SCHEMA)
        except sqlite3.Error as e:
            raise InvalidArgument(f"cannot open the database {self.path}: {e}") from None
        if mode != "wal":
            raise InvalidArgument(f"{self.path}: cannot use WAL journal mode ({mode})")
        self.db.execute("BEGIN")
        self.db.executemany("INSERT OR REPLACE INTO meta VALUES (?, ?)", [
            ("schema_version", str(SCHEMA_VERSION)), ("pymb_version", __version__),
            ("registers", "big-endian 16-bit words from the device map's first register"),
        ])
        self.db.executemany("INSERT OR REPLACE INTO states VALUES (?, ?)",
                            [(s.value, s.name.lower()) for s in State])
        self.db.execute("COMMIT")
        self._devices: dict[DeviceInfo, int] = {}
        self._in_tx = False
        self._last_trim = time.monotonic()

    def _begin(self) -> None:
        if not self._in_tx:
            self.db.execute("BEGIN")
            self._in_tx = True

    def _device_id(self, d: DeviceInfo) -> int:
        did = self._devices.get(d)
        if did is None:
            self._begin()
            self.db.execute(
                "INSERT INTO devices(bus, port, type, address, name) VALUES (?, ?, ?, ?, ?) "
                "ON CONFLICT(bus, address, type) DO UPDATE SET port = excluded.port, "
                "name = excluded.name", (d.bus, d.port, d.type, d.address, d.name))
            did = self.db.execute(
                "SELECT id FROM devices WHERE bus = ? AND address = ? AND type = ?",
                (d.bus, d.address, d.type)).fetchone()[0]
            self._devices[d] = did
        return did

    def _failed(self, e: Exception) -> OutputError:
        if self._in_tx:
            with contextlib.suppress(sqlite3.Error):
                self.db.execute("ROLLBACK")
            self._in_tx = False
        self._devices.clear()  # ids inserted by the rolled-back batch are gone
        return OutputError(f"cannot write to {self.path}: {e}; everything committed before "
                           "is intact, the batch being written was lost")

    def write(self, sample: Sample) -> None:
        """Add one sample to the current batch."""
        try:
            self._write(sample)
        except sqlite3.Error as e:
            raise self._failed(e) from None

    def _write(self, sample: Sample) -> None:
        did = self._device_id(sample.device)
        self._begin()
        data = sample.data
        cur = self.db.execute(
            "INSERT INTO samples(device_id, time_utc, monotonic, registers) VALUES (?, ?, ?, ?)",
            (did, sample.time_utc, sample.monotonic,
             _wire_bytes(data.registers)))
        sid = cur.lastrowid
        if isinstance(data, HubReading):
            c = data.channels
            values = [data.values[b * c:(b + 1) * c].tolist() for b in range(len(_HUB_FIELDS))]
            states = [data.raw_states[b * c:(b + 1) * c].tolist()
                      for b in range(len(_HUB_FIELDS))]
            # NaN is stored as NULL by sqlite3; the *_state column says why.
            self.db.executemany(
                f"INSERT INTO hub VALUES ({', '.join('?' * (2 + 2 * len(_HUB_FIELDS)))})",
                zip(repeat(sid), range(1, c + 1), *values, *states))
        else:
            self.db.execute(
                f"INSERT INTO coolpro VALUES ({', '.join('?' * (1 + len(_COOLPRO_FIELDS)))})",
                (sid, *(int(getattr(data, n)) if n in ("uptime_s", "status")
                        else getattr(data, n) for n in _COOLPRO_FIELDS)))

    def event(self, event: Event) -> None:
        """Add one event to the current batch."""
        try:
            self._event(event)
        except sqlite3.Error as e:
            raise self._failed(e) from None

    def _event(self, event: Event) -> None:
        did = None if event.device is None else self._device_id(event.device)
        self._begin()
        self.db.execute(
            "INSERT INTO events(time_utc, monotonic, bus, device_id, kind, code, message) "
            "VALUES (?, ?, ?, ?, ?, ?, ?)",
            (event.time_utc, event.monotonic, event.bus, did, event.kind, event.code,
             event.message))

    def commit(self) -> None:
        """Commit the batch (and enforce the size and age limits now and then)."""
        try:
            self._commit()
        except sqlite3.Error as e:
            raise self._failed(e) from None

    def _commit(self) -> None:
        if self._in_tx:
            self.db.execute("COMMIT")
            self._in_tx = False
        now = time.monotonic()
        if (self.max_bytes or self.max_age) and now - self._last_trim >= 5.0:
            self._last_trim = now
            self.trim()

    def _size(self) -> int:
        page_count = self.db.execute("PRAGMA page_count").fetchone()[0]
        free = self.db.execute("PRAGMA freelist_count").fetchone()[0]
        page_size = self.db.execute("PRAGMA page_size").fetchone()[0]
        return int((page_count - free) * page_size)

    def trim(self) -> int:
        """Delete the oldest data beyond the limits; returns samples deleted."""
        deleted = 0
        if self.max_age:
            cutoff = time.time() - self.max_age
            deleted += self._delete_before(
                "SELECT COALESCE(MIN(id), 0) FROM samples WHERE time_utc >= ?", (cutoff,),
                cutoff)
        if self.max_bytes:
            for _ in range(64):
                if self._size() <= self.max_bytes:
                    break
                lo, hi = self.db.execute("SELECT MIN(id), MAX(id) FROM samples").fetchone()
                if lo is not None and lo < hi:
                    # Drop the oldest tenth of the samples at a time.
                    deleted += self._delete_before("SELECT ?", (lo + max(1, (hi - lo) // 10),),
                                                   None)
                elif not self._delete_oldest_events():
                    break  # nothing left that may go
        if deleted:
            self.db.execute("PRAGMA incremental_vacuum")
        return deleted

    def _delete_oldest_events(self) -> int:
        """A long outage logs events and no samples: they must go too."""
        lo, hi = self.db.execute("SELECT MIN(id), MAX(id) FROM events").fetchone()
        if lo is None or lo >= hi:
            return 0
        self.db.execute("BEGIN")
        n = self.db.execute("DELETE FROM events WHERE id < ?",
                            (lo + max(1, (hi - lo) // 10),)).rowcount
        self.db.execute("COMMIT")
        self.db.execute("PRAGMA incremental_vacuum")
        return int(n)

    def _delete_before(self, find: str, args: tuple[Any, ...], cutoff: float | None) -> int:
        (first_kept,) = self.db.execute(find, args).fetchone()
        if first_kept == 0:  # nothing young enough: all but the newest go; the newest
            # stays so that SQLite never hands out its id (or lower ones) again: sample
            # ids are unique and increasing for the MQTT forwarder and its consumers
            first_kept = self.db.execute("SELECT MAX(id) FROM samples").fetchone()[0] or 1
        self.db.execute("BEGIN")
        try:
            self._unsent_event(first_kept)
            self.db.execute("DELETE FROM hub WHERE sample_id < ?", (first_kept,))
            self.db.execute("DELETE FROM coolpro WHERE sample_id < ?", (first_kept,))
            n = self.db.execute("DELETE FROM samples WHERE id < ?", (first_kept,)).rowcount
            if cutoff is not None:
                self.db.execute("DELETE FROM events WHERE time_utc < ?", (cutoff,))
            else:
                self.db.execute(
                    "DELETE FROM events WHERE time_utc < (SELECT COALESCE(MIN(time_utc), 0) "
                    "FROM samples)")
            self.db.execute("COMMIT")
        except BaseException:
            self.db.execute("ROLLBACK")
            raise
        return int(n)

    def _unsent_event(self, first_kept: int) -> None:
        """Never delete samples not yet forwarded (pymb.fleet's ``outbox``
        cursors) silently: an event says how many go."""
        if not self.db.execute("SELECT 1 FROM sqlite_master WHERE name = 'outbox'").fetchone():
            return
        (low,) = self.db.execute("SELECT MIN(sample_id) FROM outbox").fetchone()
        if low is None:
            return
        n, first, last = self.db.execute(
            "SELECT COUNT(*), MIN(id), MAX(id) FROM samples WHERE id > ? AND id < ?",
            (low, first_kept)).fetchone()
        if n:
            self.db.execute(
                "INSERT INTO events(time_utc, monotonic, bus, device_id, kind, code, message) "
                "VALUES (?, ?, NULL, NULL, 'trim', ?, ?)",
                (time.time(), time.monotonic(), n,
                 f"the size/age limit deleted {n} samples not yet forwarded to the MQTT "
                 f"broker (ids {first}..{last})"))

    def close(self) -> None:
        """Commit what is pending and close the database."""
        try:
            self.commit()
        finally:
            self.db.close()


# -- text formats ---------------------------------------------------------------------

CSV_COLUMNS = ["time_utc", "time", "bus", "device", "type", "address", "channel", "quantity",
               "value", "state"]


def _iso(t: float) -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(t)) + f".{int(t % 1 * 1e6):06d}Z"


def iso_utc(t: float) -> str:
    """Seconds since the epoch as ISO 8601 UTC with microseconds (``...Z``)."""
    return _iso(t)


def sample_rows(sample: Sample) -> Iterator[list[Any]]:
    """A sample as long-format rows: one per quantity (and channel)."""
    d, t = sample.device, sample.time_utc
    head = [f"{t:.6f}", _iso(t), d.bus, d.name, d.type, d.address]
    data = sample.data
    if isinstance(data, HubReading):
        c = data.channels
        for b, name in enumerate(_HUB_FIELDS):
            vals = data.values[b * c:(b + 1) * c].tolist()
            sts = data.raw_states[b * c:(b + 1) * c].tolist()
            for ch in range(c):
                v = vals[ch]
                yield [*head, ch + 1, name, "" if v != v else v, State(sts[ch]).name.lower()]
    else:
        for name in _COOLPRO_FIELDS:
            v = getattr(data, name)
            yield [*head, "", name, int(v) if name in ("uptime_s", "status") else v, "value"]


def sample_dict(sample: Sample) -> dict[str, Any]:
    """A sample as one JSON-ready object (None for no value)."""
    d = sample.device
    out: dict[str, Any] = {"time_utc": sample.time_utc, "time": _iso(sample.time_utc),
                           "monotonic": sample.monotonic, "bus": d.bus, "device": d.name,
                           "type": d.type, "address": d.address}
    data = sample.data
    if isinstance(data, HubReading):
        out["values"] = data.as_dict()
        out["states"] = {n: [State(s).name.lower() for s in data.states(n).tolist()]
                         for n in _HUB_FIELDS}
        out["unsupported"] = sorted(data.unsupported)
    else:
        out["values"] = {n: (int(getattr(data, n)) if n in ("uptime_s", "status")
                             else _finite(getattr(data, n))) for n in _COOLPRO_FIELDS}
        out["status_flags"] = [f.name for f in type(data.status) if f in data.status]
    return out


def event_dict(e: Event) -> dict[str, Any]:
    """An event as a JSON-ready object."""
    return {"time_utc": e.time_utc, "time": _iso(e.time_utc), "event": e.kind, "bus": e.bus,
            "device": None if e.device is None else e.device.name, "code": e.code,
            "message": e.message}


class _TextSink:
    f: IO[str]

    def __init__(self, path: str) -> None:
        self.path = path
        self._own = path != "-"
        try:
            self.f = (open(path, "a", encoding="utf-8", newline="")  # noqa: SIM115
                      if self._own else sys.stdout)
        except OSError as e:
            raise InvalidArgument(f"cannot open {path}: {e.strerror}") from None

    def commit(self) -> None:
        try:
            self.f.flush()
        except OSError as e:
            raise OutputError(f"cannot write to {self.path}: {e.strerror}") from None

    def close(self) -> None:
        try:
            self.commit()
        finally:
            if self._own:
                with contextlib.suppress(OSError):
                    self.f.close()


class CsvSink(_TextSink):
    """Long-format CSV (one row per value); events as rows with quantity ``event``."""

    def __init__(self, path: str) -> None:
        super().__init__(path)
        self.w = csv.writer(self.f)
        if not self._own or self.f.tell() == 0:
            self.w.writerow(CSV_COLUMNS)

    def write(self, sample: Sample) -> None:
        try:
            self.w.writerows(sample_rows(sample))
        except OSError as e:
            raise OutputError(f"cannot write to {self.path}: {e.strerror}") from None

    def event(self, e: Event) -> None:
        try:
            self._event(e)
        except OSError as err:
            raise OutputError(f"cannot write to {self.path}: {err.strerror}") from None

    def _event(self, e: Event) -> None:
        d = e.device
        self.w.writerow([f"{e.time_utc:.6f}", _iso(e.time_utc), e.bus,
                         "" if d is None else d.name, "" if d is None else d.type,
                         "" if d is None else d.address, "", f"event:{e.kind}",
                         "" if e.code is None else e.code, e.message])


class JsonlSink(_TextSink):
    """JSON Lines: one object per sample or event."""

    def write(self, sample: Sample) -> None:
        try:
            self.f.write(json.dumps(sample_dict(sample), allow_nan=False) + "\n")
        except OSError as e:
            raise OutputError(f"cannot write to {self.path}: {e.strerror}") from None

    def event(self, e: Event) -> None:
        try:
            self.f.write(json.dumps(event_dict(e)) + "\n")
        except OSError as err:
            raise OutputError(f"cannot write to {self.path}: {err.strerror}") from None


FORMATS = ("sqlite", "csv", "jsonl", "influx")


def open_sink(fmt: str, path: str, *, max_bytes: int | None = None,
              max_age: float | None = None) -> Sink:
    """A sink of format ``sqlite``, ``csv``, ``jsonl`` or ``influx`` at ``path``
    (``-``: stdout)."""
    if fmt == "sqlite":
        if path == "-":
            raise InvalidArgument(
                "SQLite needs a file; use --format csv, jsonl or influx for stdout")
        return SqliteSink(path, max_bytes=max_bytes, max_age=max_age)
    if fmt == "csv":
        return CsvSink(path)
    if fmt == "jsonl":
        return JsonlSink(path)
    if fmt == "influx":  # InfluxDB line protocol (pymb.fleet.influx)
        from pymb.fleet.influx import InfluxSink
        return InfluxSink(path)
    raise InvalidArgument(f"unknown output format {fmt!r}; use one of {', '.join(FORMATS)}")


def export_csv(db_path: str, out: IO[str], *, device: str | None = None,
               since: float | None = None, events: bool = False) -> int:
    """Write a pymb SQLite database out as long-format CSV; returns rows."""
    if not Path(db_path).exists():
        raise InvalidArgument(f"no such database: {db_path}")
    # A URI, escaped: '%', '#' and '?' in a file name are the file name's.
    db = sqlite3.connect(Path(db_path).resolve().as_uri() + "?mode=ro", uri=True)
    try:
        w = csv.writer(out)
        w.writerow(CSV_COLUMNS)
        rows = 0
        where, args = _filters(device, since)
        for sql, fields in (
            ("SELECT s.time_utc, d.bus, d.name, d.type, d.address, NULL, {cols} FROM coolpro c "
             "JOIN samples s ON s.id = c.sample_id JOIN devices d ON d.id = s.device_id",
             _COOLPRO_FIELDS),
            ("SELECT s.time_utc, d.bus, d.name, d.type, d.address, h.channel, {cols} FROM hub h "
             "JOIN samples s ON s.id = h.sample_id JOIN devices d ON d.id = s.device_id",
             _HUB_FIELDS),
        ):
            hub = fields is _HUB_FIELDS
            cols = ", ".join(fields + ([f"{f}_state" for f in fields] if hub else []))
            q = sql.format(cols=cols) + where + " ORDER BY s.id" + (", h.channel" if hub else "")
            for r in db.execute(q, args):
                head = [f"{r[0]:.6f}", _iso(r[0]), r[1], r[2], r[3], r[4]]
                n = len(fields)
                for i, name in enumerate(fields):
                    v = r[6 + i]
                    state = State(r[6 + n + i]).name.lower() if hub else "value"
                    w.writerow([*head, "" if r[5] is None else r[5], name,
                                "" if v is None else v, state])
                    rows += 1
        if events:
            q = ("SELECT e.time_utc, e.bus, d.name, d.type, d.address, e.kind, e.code, e.message "
                 "FROM events e LEFT JOIN devices d ON d.id = e.device_id")
            ew, eargs = _filters(device, since, table="e")
            for r in db.execute(q + ew + " ORDER BY e.id", eargs):
                w.writerow([f"{r[0]:.6f}", _iso(r[0]), r[1], r[2] or "", r[3] or "",
                            "" if r[4] is None else r[4], "", f"event:{r[5]}",
                            "" if r[6] is None else r[6], r[7]])
                rows += 1
        return rows
    except sqlite3.Error as e:
        raise InvalidArgument(f"{db_path} is not a readable pymb database: {e}") from None
    finally:
        db.close()


def _filters(device: str | None, since: float | None,
             table: str = "s") -> tuple[str, Sequence[Any]]:
    parts: list[str] = []
    args: list[Any] = []
    if device is not None:
        parts.append("d.name = ?")
        args.append(device)
    if since is not None:
        parts.append(f"{table}.time_utc >= ?")
        args.append(since)
    return (" WHERE " + " AND ".join(parts)) if parts else "", args
