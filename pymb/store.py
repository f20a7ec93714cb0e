"""Where logged data goes: SQLite (the default), CSV, JSON Lines.

SQLite: WAL journal, ``synchronous=NORMAL``, commits in batches. A
transaction that committed survives the process being killed (even SIGKILL);
what was not yet committed, at most one batch, is lost. Format 2 stores the
raw registers once (a BLOB of big-endian 16-bit words, as on the wire, from
the device map's first register) and decodes them in plain-SQL views that
``sqlite3`` queries directly, through the time index::

    SELECT time, device, channel, temperature_c FROM hub_readings
     WHERE channel = 3 ORDER BY time_utc DESC LIMIT 10;

Interfaces other parts of pymb rely on (keep them stable):

- :class:`SqliteSink` (``write``/``event``/``commit``/``close``), with
  ``max_bytes`` (database file plus WAL), ``max_age`` and ``on_change``.
- :func:`samples_after` ``(db, sample_id, limit)``: committed samples after
  an id, in id order, decoded (:class:`StoredSample`): the reader of a
  store-and-forward publisher.
- An ``outbox(name TEXT PRIMARY KEY, sample_id INTEGER)`` table, if a
  forwarder creates one, holds its cursors (the last sample id each sent);
  trimming past the lowest records a ``trim`` event whose code is the
  number of unsent samples deleted (and whose message names their ids).
- :func:`schema_version`; :func:`export_csv` reads formats 1 and 2.
"""

from __future__ import annotations

import contextlib
import csv
import functools
import json
import math
import os
import sqlite3
import sys
import time
from array import array
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, Protocol

from pymb import __version__, _native
from pymb.devices import HUB, CoolProStatus, CoolProTelemetry, HubReading, State, decode_hub
from pymb.devices.maps import COOLPRO, Type
from pymb.devices.readings import (
    INTEGRAL_QUANTITIES,
    STATE_NAMES,
    reading_dict,
    telemetry_values,
)
from pymb.errors import InvalidArgument

__all__ = [
    "CsvSink",
    "DeviceInfo",
    "Event",
    "JsonlSink",
    "OnChange",
    "OutputError",
    "Sample",
    "Sink",
    "SqliteSink",
    "StoredSample",
    "open_sink",
    "samples_after",
    "schema_version",
]

_COOLPRO_FIELDS = [r.name for r in COOLPRO.group("telemetry")]
_HUB_FIELDS = [b.name for b in HUB.blocks]
_NOT_READ = int(State.NOT_READ)


class OutputError(Exception):
    """Logged data could not be written (disk full, read-only database or
    file, I/O error). What was committed before is intact; the batch being
    written when it happened is lost."""


@dataclass(frozen=True)
class DeviceInfo:
    """A logged device: its bus, port, type (``coolpro``/``hub``), address,
    name; for a hub, its channels (0: as read) and humidity unit (1 or 0.1 %,
    one for all channels or a tuple, one per channel)."""

    bus: str
    port: str
    type: str
    address: int
    name: str
    channels: int = 0
    humidity_unit: float | tuple[float, ...] = 0.1


@dataclass(frozen=True)
class Sample:
    """One reading of one device, time-stamped when it completed."""

    device: DeviceInfo
    time_utc: float
    monotonic: float
    data: CoolProTelemetry | HubReading


@dataclass(frozen=True)
class StoredSample(Sample):
    """A sample read back from a database (what :func:`samples_after`
    yields): the :class:`Sample` the logger wrote, decoded again from the
    stored registers, plus ``id``, its id in the database (unique and
    increasing). A hub channel an ``--on-change`` sample did not store has
    the state ``NOT_READ`` and no value. :func:`sample_dict` and
    :func:`sample_rows` take it as they take a live sample."""

    id: int


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


#: Rows one multi-row INSERT of samples carries at most (5 values each, far
#: below SQLite's limit of bound variables).
_ROWS_PER_INSERT = 64


@functools.lru_cache(maxsize=_ROWS_PER_INSERT)
def _insert_rows(n: int) -> str:
    """The INSERT of ``n`` sample rows (device_id, time_utc, monotonic,
    registers, unsupported)."""
    return ("INSERT INTO samples(device_id, time_utc, monotonic, registers, unsupported) "
            "VALUES " + ", ".join(["(?, ?, ?, ?, ?)"] * n))


def _wire_bytes(regs: array[int]) -> bytes:
    out = array("H", regs)
    if sys.byteorder == "little":
        out.byteswap()
    return out.tobytes()


def _finite(v: float) -> float | None:
    return None if math.isnan(v) else v


class Sink(Protocol):
    """What the logger writes to.

    A sink that is done with a sample when :meth:`write` returns (it has
    copied or written what it needs) may say so with a class attribute
    ``keeps_samples = False``: the logger then reads later hub sweeps into
    that sample's arrays. pymb's own sinks do; any other sink is assumed to
    keep what it is given.
    """

    def write(self, sample: Sample) -> None:
        """Add a sample to the current batch."""

    def event(self, event: Event) -> None:
        """Add an event to the current batch."""

    def commit(self) -> None:
        """Make the batch durable."""

    def close(self) -> None:
        """Commit and release the output."""


# -- SQLite ---------------------------------------------------------------------------
#
# Format 2 (SCHEMA_VERSION): what the wire gave, stored once.
#
#   samples      one row per stored reading: device, UTC and monotonic time, the raw
#                registers as a BLOB of big-endian 16-bit words from the map's first
#                register (hub: registers 31..730, block-major, 1,400 bytes; CoolPro:
#                input registers 0..7, 16 bytes), and the hub blocks the firmware lacks
#                (a bit mask, bit = block index). Indexed by time_utc.
#   hub_changes  --on-change hub readings: only the channels that moved past their
#                deadband (or whose heartbeat came), 7 registers each (14 bytes, block
#                order); their samples row has registers NULL.
#   devices      one row per device configuration (bus, port, type, address, name,
#                channels, humidity units); channels: a hub's channels with the humidity
#                unit of each (1: 0.1 %, 0: 1 %).
#   events       faults, reconnects, trimming.
#
# Decoded values are views, in plain SQL (no extension; Debian 12's sqlite3 3.40):
# hub_readings / hub and coolpro_readings / coolpro, with the same columns as the tables
# of format 1. The decoding rules of the C core are written out in SQL below, generated
# from the device maps, and tested value by value against the C decoder.

SCHEMA_VERSION = 2
PAGE_SIZE = 8192  #: 5 hub sweeps a page (4,096 would hold 2: 2,048 B a sweep)
_WAL_MIN, _WAL_MAX = 256 * 1024, 8 * 1024 * 1024
MIN_BYTES = 1_000_000  #: the smallest size bound accepted (schema pages and a WAL budget)

_DIGITS = "'123456789ABCDEF'"  # instr() of a hex digit in this is its value ('0' -> 0)


def _digit(h: str, i: int) -> str:
    return f"instr({_DIGITS}, substr({h}, {i}, 1))"


def _u16(h: str) -> str:
    """The unsigned value of 4 hex digits ``h`` (an SQL expression)."""
    return (f"({_digit(h, 1)} * 4096 + {_digit(h, 2)} * 256 + {_digit(h, 3)} * 16 + "
            f"{_digit(h, 4)})")


def _hub_columns() -> tuple[list[str], list[str]]:
    """SQL for the hub's decoded values and states, one pair per block."""
    values, states = [], []
    for b in HUB.blocks:
        h = (f"hex(CASE WHEN s.registers IS NULL THEN substr(x.registers, {2 * b.index + 1}, 2)"
             f" ELSE substr(s.registers, {2 * b.index * HUB.channels + 1} + 2 * (c.channel - 1),"
             f" 2) END)")
        unsupported = f"((s.unsupported >> {b.index}) & 1)"
        offline = "'FFFF'"
        if b.name == "humidity_pct":
            tenths, one = (f"'{m:04X}'" for m, _ in b.markers[2:0:-1])
            no_sensor = f"{h} = CASE WHEN c.humidity_tenths THEN {tenths} ELSE {one} END"
        else:
            no_sensor = "0"
        if b.type is Type.SIGN_MAGNITUDE:
            raw = (f"(CASE WHEN {_digit(h, 1)} >= 8 THEN -1 ELSE 1 END) * (({_digit(h, 1)} % 8)"
                   f" * 4096 + {_digit(h, 2)} * 256 + {_digit(h, 3)} * 16 + {_digit(h, 4)})")
        elif b.type is Type.I16:
            raw = f"({_u16(h)} - CASE WHEN {_digit(h, 1)} >= 8 THEN 65536 ELSE 0 END)"
        else:
            raw = _u16(h)
        if b.per_channel_scales:
            scaled = f"CASE WHEN c.humidity_tenths THEN {raw} / 10.0 ELSE {raw} * 1.0 END"
        elif b.scale == 0.1:
            scaled = f"{raw} / 10.0"
        else:
            scaled = f"{raw} * {b.scale:g}.0" if b.scale == int(b.scale) else f"{raw} * {b.scale}"
        values.append(f"CASE WHEN {unsupported} OR {h} = {offline} OR ({no_sensor}) THEN NULL "
                      f"ELSE {scaled} END AS {b.name}")
        states.append(f"CASE WHEN {unsupported} THEN {int(State.UNSUPPORTED)} "
                      f"WHEN {h} = {offline} THEN {int(State.OFFLINE)} "
                      f"WHEN {no_sensor} THEN {int(State.NO_SENSOR)} "
                      f"ELSE {int(State.VALUE)} END AS {b.name}_state")
    return values, states


def _coolpro_columns() -> list[str]:
    first = COOLPRO.span("telemetry")[1]
    out = []
    for r in COOLPRO.group("telemetry"):
        i = r.address - first

        def word(k: int) -> str:
            return _u16(f"hex(substr(s.registers, {2 * k + 1}, 2))")

        if r.type is Type.U32_LE_WORDS:
            expr = f"{word(i)} + 65536 * {word(i + 1)}"
        elif r.scale == 0.001:
            expr = f"{word(i)} / 1000.0"
        else:
            expr = word(i)
        out.append(f"{expr} AS {r.name}")
    return out


_HUB_VALUES, _HUB_STATES = _hub_columns()
_TIME = "strftime('%Y-%m-%d %H:%M:%f', s.time_utc, 'unixepoch')"

_SCHEMA = f"""
CREATE TABLE IF NOT EXISTS meta(key TEXT PRIMARY KEY, value TEXT);
CREATE TABLE IF NOT EXISTS devices(
    id INTEGER PRIMARY KEY, bus TEXT NOT NULL, port TEXT NOT NULL, type TEXT NOT NULL,
    address INTEGER NOT NULL, name TEXT NOT NULL,
    channels INTEGER NOT NULL DEFAULT 0,   -- hub: channels logged
    humidity_units TEXT NOT NULL DEFAULT '', -- hub: '0.1', '1', or one per channel
    UNIQUE(bus, port, type, address, name, channels, humidity_units));
CREATE TABLE IF NOT EXISTS channels(
    device_id INTEGER NOT NULL REFERENCES devices(id), channel INTEGER NOT NULL,
    humidity_tenths INTEGER NOT NULL,  -- 1: the channel's humidity is in 0.1 %, 0: in 1 %
    PRIMARY KEY(device_id, channel)) WITHOUT ROWID;
CREATE TABLE IF NOT EXISTS samples(
    id INTEGER PRIMARY KEY, device_id INTEGER NOT NULL REFERENCES devices(id),
    time_utc REAL NOT NULL, monotonic REAL NOT NULL,
    registers BLOB,  -- big-endian 16-bit words from the map's first register; NULL: hub_changes
    unsupported INTEGER NOT NULL DEFAULT 0  -- hub blocks the firmware lacks (bit = block)
);
CREATE INDEX IF NOT EXISTS samples_time ON samples(time_utc);
CREATE TABLE IF NOT EXISTS hub_changes(
    device_id INTEGER NOT NULL, channel INTEGER NOT NULL, time_utc REAL NOT NULL,
    sample_id INTEGER NOT NULL REFERENCES samples(id),
    registers BLOB NOT NULL,  -- the channel's 7 registers, block order, big-endian
    PRIMARY KEY(device_id, channel, time_utc, sample_id)) WITHOUT ROWID;
CREATE TABLE IF NOT EXISTS states(code INTEGER PRIMARY KEY, name TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS events(
    id INTEGER PRIMARY KEY, time_utc REAL NOT NULL, monotonic REAL NOT NULL, bus TEXT,
    device_id INTEGER REFERENCES devices(id), kind TEXT NOT NULL, code INTEGER,
    message TEXT NOT NULL);
CREATE INDEX IF NOT EXISTS events_time ON events(time_utc);
-- Views are recreated on every open (UTC times with milliseconds; no 'subsec', which
-- needs SQLite 3.42 while Debian 12 has 3.40).
DROP VIEW IF EXISTS hub;
DROP VIEW IF EXISTS coolpro;
DROP VIEW IF EXISTS coolpro_readings;
DROP VIEW IF EXISTS hub_readings;
DROP VIEW IF EXISTS event_log;
CREATE VIEW hub_readings AS
    SELECT {_TIME} AS time, s.time_utc, d.name AS device, d.address, s.id AS sample_id,
           c.channel, {", ".join(_HUB_VALUES)}, {", ".join(_HUB_STATES)}
      FROM samples s JOIN devices d ON d.id = s.device_id
      JOIN channels c ON c.device_id = s.device_id
      LEFT JOIN hub_changes x ON x.device_id = s.device_id AND x.channel = c.channel
                             AND x.time_utc = s.time_utc AND x.sample_id = s.id
     WHERE s.registers IS NOT NULL OR x.registers IS NOT NULL;
CREATE VIEW hub AS
    SELECT sample_id, channel, {", ".join(b.name for b in HUB.blocks)},
           {", ".join(b.name + "_state" for b in HUB.blocks)} FROM hub_readings;
CREATE VIEW coolpro_readings AS
    SELECT {_TIME} AS time, s.time_utc, d.name AS device, d.address, s.id AS sample_id,
           {", ".join(_coolpro_columns())}
      FROM samples s JOIN devices d ON d.id = s.device_id WHERE d.type = 'coolpro';
CREATE VIEW coolpro AS
    SELECT sample_id, {", ".join(_COOLPRO_FIELDS)} FROM coolpro_readings;
CREATE VIEW event_log AS
    SELECT strftime('%Y-%m-%d %H:%M:%f', e.time_utc, 'unixepoch') AS time, e.time_utc, e.bus,
           d.name AS device, e.kind, e.code, e.message
      FROM events e LEFT JOIN devices d ON d.id = e.device_id;
"""


def schema_version(db: sqlite3.Connection) -> int | None:
    """The pymb format of an open database: 1, 2, ..., 0 if empty, None if not pymb's."""
    tables = {n for (n,) in db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
    if not tables:
        return 0
    if "meta" not in tables or "samples" not in tables:
        return None
    row = db.execute("SELECT value FROM meta WHERE key = 'schema_version'").fetchone()
    try:
        return int(row[0]) if row else None
    except ValueError:
        return None


def _humidity_units(d: DeviceInfo, channels: int) -> tuple[str, bytes]:
    u = d.humidity_unit
    units = [u] * channels if isinstance(u, (int, float)) else list(u)
    if len(units) != channels:
        raise InvalidArgument(f"{d.name}: {len(units)} humidity units for {channels} channels")
    tenths = bytes(0 if x == 1 else 1 for x in units)
    text = f"{units[0]:g}" if len(set(units)) == 1 else ",".join(f"{x:g}" for x in units)
    return text, tenths


@dataclass
class OnChange:
    """Report by exception (``pymb log --on-change``).

    A hub channel is stored when one of its quantities moved more than its
    ``deadband`` (engineering units, by quantity name; 0 or absent: any change)
    since the channel was last stored, when a state changes (offline, no
    sensor, unsupported), and at least every ``heartbeat`` seconds. A
    CoolPro sample is stored on the same rules over its quantities (its
    uptime only when it restarts). The value at time t is then the last
    stored row at or before t (see the README).
    """

    heartbeat: float = 60.0
    deadband: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not (self.heartbeat > 0 and math.isfinite(self.heartbeat)):
            raise InvalidArgument(f"the heartbeat must be a positive number of seconds, "
                                  f"got {self.heartbeat!r}")
        known = set(_HUB_FIELDS) | set(_COOLPRO_FIELDS) - INTEGRAL_QUANTITIES
        for name, value in self.deadband.items():
            if name not in known:
                raise InvalidArgument(f"no quantity {name!r} for a deadband; use one of "
                                      f"{', '.join(sorted(known))}")
            if not (value >= 0 and math.isfinite(value)):
                raise InvalidArgument(f"deadband of {name} must be >= 0, got {value!r}")


class _HubChanges:
    """Which channels of a hub sweep to store, against what was last stored."""

    def __init__(self, rules: OnChange, channels: int) -> None:
        self.rules = rules
        self.channels = channels
        self.bands = [rules.deadband.get(b.name, 0.0) for b in HUB.blocks]
        self.regs: array[int] | None = None  # the previous sweep's registers
        self.mask = -1
        self.values = array("d", bytes(8 * 7 * channels))  # last stored, per channel
        self.states = array("B", bytes(7 * channels))
        self.due = [0.0] * channels  # heartbeat deadline per channel (monotonic)
        self.next_due = 0.0

    def changed(self, data: HubReading, now: float) -> list[int]:
        """0-based channels to store now (and remembers them as stored)."""
        c = self.channels
        regs = data.registers
        if self.regs is None or data.unsupported_mask != self.mask:
            pick = set(range(c))
        else:
            pick = set()
            prev = self.regs
            n = HUB.channels
            for b in range(len(HUB.blocks)):
                lo = b * n
                if regs[lo:lo + c] == prev[lo:lo + c]:
                    continue  # nothing in this block moved since the last sweep
                band = self.bands[b]
                vals, sts = data.values, data.raw_states
                for ch in range(c):
                    if ch in pick or regs[lo + ch] == prev[lo + ch]:
                        continue
                    i = b * c + ch
                    if sts[i] != self.states[i] or (
                            sts[i] == 0 and abs(vals[i] - self.values[i]) > band):
                        pick.add(ch)
            if now >= self.next_due:
                pick.update(ch for ch in range(c) if now >= self.due[ch])
        self.regs = array("H", regs)
        self.mask = data.unsupported_mask
        if pick:
            vals, sts = data.values, data.raw_states
            for ch in pick:
                for b in range(len(HUB.blocks)):
                    i = b * c + ch
                    self.values[i] = vals[i]
                    self.states[i] = sts[i]
                self.due[ch] = now + self.rules.heartbeat
            self.next_due = min(self.due)
        return sorted(pick)


class _CoolProChanges:
    _FIELDS = ("input_voltage_v", "input_current_a", "output_voltage_v", "output_current_a",
               "temperature_c")

    def __init__(self, rules: OnChange) -> None:
        self.rules = rules
        self.last: CoolProTelemetry | None = None
        self.due = 0.0

    def changed(self, data: CoolProTelemetry, now: float) -> bool:
        last = self.last
        store = (last is None or now >= self.due or data.status != last.status
                 or data.uptime_s < last.uptime_s
                 or any(abs(getattr(data, f) - getattr(last, f))
                        > self.rules.deadband.get(f, 0.0) for f in self._FIELDS))
        if store:
            self.last = data
            self.due = now + self.rules.heartbeat
        return store


class SqliteSink:
    """Writes samples and events to a SQLite database of format 2 (created if
    missing; a database of an older pymb format is refused, never mixed).

    ``max_bytes`` / ``max_age`` (seconds) bound the database: past the size
    (the database file and its WAL together, checked at every commit) or the
    age, the oldest samples and events are deleted and their pages reused.
    ``on_change`` stores readings by exception (see :class:`OnChange`).

    If the database has an ``outbox(name TEXT PRIMARY KEY, sample_id INTEGER)``
    table (a forwarder's cursors: the last sample each has sent), trimming
    past the lowest cursor records a ``trim`` event saying how many samples
    (and which ids) were deleted before they were sent.
    """

    keeps_samples = False  #: see :class:`Sink`

    def __init__(self, path: str | os.PathLike[str], *, max_bytes: int | None = None,
                 max_age: float | None = None, on_change: OnChange | None = None) -> None:
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
        self.trimmed = 0  #: samples deleted by the size and age limits so far
        self.stored = 0  #: samples written (on-change: those that changed)
        try:
            _remove_stale_creations(self.path)
            if not self.path.exists():
                _create(self.path)
            self.db = sqlite3.connect(self.path, isolation_level=None, check_same_thread=False)
        except (sqlite3.Error, OSError) as e:
            raise InvalidArgument(f"cannot open the database {self.path}: {e}") from None
        try:
            self._open()
        except sqlite3.Error as e:
            self.db.close()
            raise InvalidArgument(f"cannot open the database {self.path}: {e}") from None
        except InvalidArgument:
            self.db.close()
            raise
        self._devices: dict[DeviceInfo, tuple[int, int]] = {}
        self._changes: dict[int, _HubChanges | _CoolProChanges] = {}
        self._in_tx = False
        self._tx_bytes = 0  # registers written in the open batch (size limit only)
        self._last_age_trim = time.monotonic()
        self._wal = Path(f"{self.path}-wal")

    def _open(self) -> None:
        db = self.db
        version = schema_version(db)
        if version is None:
            raise InvalidArgument(f"{self.path} is not a pymb database; log to a new file")
        if version not in (0, SCHEMA_VERSION):
            older = version < SCHEMA_VERSION
            raise InvalidArgument(
                f"{self.path} holds pymb format {version}, this pymb writes format "
                f"{SCHEMA_VERSION}; " + ("log to a new file (pymb export still reads this one)"
                                        if older else "use the newer pymb that wrote it"))
        if version == 0:
            db.execute(f"PRAGMA page_size = {PAGE_SIZE}")
            db.execute("PRAGMA auto_vacuum = INCREMENTAL")
        mode = db.execute("PRAGMA journal_mode = WAL").fetchone()[0]
        if mode != "wal":
            raise InvalidArgument(f"{self.path}: cannot use WAL journal mode ({mode})")
        db.execute("PRAGMA synchronous = NORMAL")
        self.page_size = int(db.execute("PRAGMA page_size").fetchone()[0])
        self.wal_budget = _WAL_MAX
        if self.max_bytes is not None:
            self.wal_budget = max(_WAL_MIN, min(_WAL_MAX, self.max_bytes // 16))
        # Checkpoint at half the budget; truncate the WAL file back to it afterwards.
        db.execute(f"PRAGMA wal_autocheckpoint = {max(16, self.wal_budget // 2 // self.page_size)}")
        db.execute(f"PRAGMA journal_size_limit = {self.wal_budget // 2}")
        db.execute("BEGIN")
        for stmt in _statements(_SCHEMA):
            db.execute(stmt)
        db.executemany("INSERT OR REPLACE INTO meta VALUES (?, ?)", [
            ("schema_version", str(SCHEMA_VERSION)), ("pymb_version", __version__),
            ("registers", "big-endian 16-bit words from the device map's first register"),
        ])
        db.executemany("INSERT OR REPLACE INTO states VALUES (?, ?)",
                       [(s.value, s.name.lower()) for s in State])
        db.execute("COMMIT")

    def _begin(self) -> None:
        if not self._in_tx:
            self.db.execute("BEGIN")
            self._in_tx = True

    def _device_id(self, d: DeviceInfo, data: Any) -> tuple[int, int]:
        """(device id, channels) of a device configuration, inserted on first use."""
        got = self._devices.get(d)
        if got is not None:
            return got
        channels, units, tenths = 0, "", b""
        if d.type == "hub":
            channels = data.channels if isinstance(data, HubReading) else (
                d.channels or HUB.channels)
            units, tenths = _humidity_units(d, channels)
        key = (d.bus, d.port, d.type, d.address, d.name, channels, units)
        self._begin()
        row = self.db.execute(
            "SELECT id FROM devices WHERE bus = ? AND port = ? AND type = ? AND address = ? "
            "AND name = ? AND channels = ? AND humidity_units = ?", key).fetchone()
        if row is None:
            did = self.db.execute(
                "INSERT INTO devices(bus, port, type, address, name, channels, humidity_units) "
                "VALUES (?, ?, ?, ?, ?, ?, ?)", key).lastrowid
            self.db.executemany("INSERT INTO channels VALUES (?, ?, ?)",
                                [(did, ch + 1, t) for ch, t in enumerate(tenths)])
        else:
            did = row[0]
        got = (int(did), channels)  # type: ignore[arg-type]
        if not isinstance(data, Event):
            self._devices[d] = got
        return got

    def _failed(self, e: Exception) -> OutputError:
        if self._in_tx:
            with contextlib.suppress(sqlite3.Error):
                self.db.execute("ROLLBACK")
            self._in_tx = False
        self._devices.clear()  # ids inserted by the rolled-back batch are gone
        self._changes.clear()  # what was "last stored" may be rolled back too
        return OutputError(f"cannot write to {self.path}: {e}; everything committed before "
                           "is intact, the batch being written was lost")

    def write(self, sample: Sample) -> None:
        """Add one sample to the current batch. Under a size limit, a batch
        that grows past a quarter of the WAL budget is committed at once, so
        the bound holds at any write rate."""
        try:
            self._write(sample)
            if self.max_bytes is not None:
                self._tx_bytes += 2 * len(sample.data.registers) + 64
                if self._tx_bytes >= self.wal_budget // 4:
                    self._commit()
        except sqlite3.Error as e:
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
        try:
            rows = [(self._device_id(s.device, s.data)[0], s.time_utc, s.monotonic,
                     _wire_bytes(s.data.registers),
                     s.data.unsupported_mask if isinstance(s.data, HubReading) else 0)
                    for s in samples]
            bounded = self.max_bytes is not None
            quarter = self.wal_budget // 4
            self._begin()
            i = 0
            while i < len(rows):
                # A statement ends where write() one by one would commit: at
                # the row that brings the batch to a quarter of the WAL budget.
                j, size = i, self._tx_bytes
                while j < len(rows) and j - i < _ROWS_PER_INSERT:
                    size += len(rows[j][3]) + 64
                    j += 1
                    if bounded and size >= quarter:
                        break
                chunk = rows[i:j]
                i = j
                self.db.execute(_insert_rows(len(chunk)), [v for row in chunk for v in row])
                self.stored += len(chunk)
                if bounded:
                    self._tx_bytes = size
                    if size >= quarter:
                        self._commit()
                        self._begin()
        except sqlite3.Error as e:
            raise self._failed(e) from None

    def _write(self, sample: Sample) -> None:
        data = sample.data
        did = self._device_id(sample.device, data)[0]
        self._begin()
        if self.on_change is None:
            self.db.execute(
                "INSERT INTO samples(device_id, time_utc, monotonic, registers, unsupported) "
                "VALUES (?, ?, ?, ?, ?)",
                (did, sample.time_utc, sample.monotonic, _wire_bytes(data.registers),
                 data.unsupported_mask if isinstance(data, HubReading) else 0))
            self.stored += 1
            return
        rules = self._changes.get(did)
        if isinstance(data, HubReading):
            if not isinstance(rules, _HubChanges) or rules.channels != data.channels:
                rules = self._changes[did] = _HubChanges(self.on_change, data.channels)
            pick = rules.changed(data, sample.monotonic)
            if not pick:
                return
            sid = self.db.execute(
                "INSERT INTO samples(device_id, time_utc, monotonic, registers, unsupported) "
                "VALUES (?, ?, ?, NULL, ?)",
                (did, sample.time_utc, sample.monotonic, data.unsupported_mask)).lastrowid
            regs = data.registers
            n = HUB.channels
            blocks = range(len(HUB.blocks))
            self.db.executemany(
                "INSERT INTO hub_changes VALUES (?, ?, ?, ?, ?)",
                [(did, ch + 1, sample.time_utc, sid,
                  _wire_bytes(array("H", [regs[b * n + ch] for b in blocks])))
                 for ch in pick])
        else:
            if not isinstance(rules, _CoolProChanges):
                rules = self._changes[did] = _CoolProChanges(self.on_change)
            if not rules.changed(data, sample.monotonic):
                return
            self.db.execute(
                "INSERT INTO samples(device_id, time_utc, monotonic, registers) "
                "VALUES (?, ?, ?, ?)",
                (did, sample.time_utc, sample.monotonic, _wire_bytes(data.registers)))
        self.stored += 1

    def event(self, event: Event) -> None:
        """Add one event to the current batch."""
        try:
            self._event(event)
        except sqlite3.Error as e:
            raise self._failed(e) from None

    def _event(self, event: Event) -> None:
        did = None if event.device is None else self._device_id(event.device, event)[0]
        self._begin()
        self.db.execute(
            "INSERT INTO events(time_utc, monotonic, bus, device_id, kind, code, message) "
            "VALUES (?, ?, ?, ?, ?, ?, ?)",
            (event.time_utc, event.monotonic, event.bus, did, event.kind, event.code,
             event.message))

    def commit(self) -> None:
        """Commit the batch, then hold the size limit (database and WAL) and,
        every few seconds, the age limit."""
        try:
            self._commit()
        except sqlite3.Error as e:
            raise self._failed(e) from None

    def _commit(self) -> None:
        if self._in_tx:
            self.db.execute("COMMIT")
            self._in_tx = False
        self._tx_bytes = 0
        if self.max_bytes is not None:
            if self._wal_bytes() > self.wal_budget:
                # A reader held the WAL back: catch up if it has let go (without
                # waiting for it: a forwarder may be reading).
                self._checkpoint()
            count, free = self._pages()
            if (count - free) * self.page_size > self._room():
                self.trim()
                return
        if self.max_age is not None and time.monotonic() - self._last_age_trim >= 5.0:
            self.trim()

    def _room(self) -> int:
        """Bytes the database's pages may take: the limit less the WAL (its
        budget, or what it holds now if more)."""
        assert self.max_bytes is not None
        return self.max_bytes - max(self.wal_budget, self._wal_bytes())

    def _checkpoint(self) -> None:
        """Copy the WAL into the database and truncate it, unless a reader
        still needs it (then next time; never wait for a reader)."""
        self.db.execute("PRAGMA busy_timeout = 0")
        try:
            self.db.execute("PRAGMA wal_checkpoint(TRUNCATE)").fetchone()
        finally:
            self.db.execute("PRAGMA busy_timeout = 5000")

    def _wal_bytes(self) -> int:
        try:
            return self._wal.stat().st_size
        except OSError:
            return 0

    def _pages(self) -> tuple[int, int]:
        count = self.db.execute("PRAGMA page_count").fetchone()[0]
        free = self.db.execute("PRAGMA freelist_count").fetchone()[0]
        return int(count), int(free)

    def _size(self) -> int:
        """Bytes the data takes: pages in use plus the WAL."""
        count, free = self._pages()
        return (count - free) * self.page_size + self._wal_bytes()

    def trim(self) -> int:
        """Delete the oldest data beyond the limits; returns samples deleted."""
        try:
            return self._trim()
        except sqlite3.Error as e:
            raise self._failed(e) from None

    def _trim(self) -> int:
        deleted = 0
        if self.max_age is not None:
            self._last_age_trim = time.monotonic()
            cutoff = time.time() - self.max_age
            deleted += self._delete_before(
                "SELECT COALESCE(MIN(id), 0) FROM samples WHERE time_utc >= ?", (cutoff,),
                cutoff)
        if self.max_bytes is not None:
            # Delete down to 95 % of the room left beside the WAL, so the freed
            # pages take the next inserts and the file stops growing.
            room = self._room()
            for _ in range(64):
                count, free = self._pages()
                used = (count - free) * self.page_size
                if used <= room:
                    break
                lo, hi = self.db.execute("SELECT MIN(id), MAX(id) FROM samples").fetchone()
                if lo is not None and lo < hi:
                    share = min(0.5, (used - 0.95 * room) / used)
                    step = max(1, int((hi - lo) * share))
                    deleted += self._delete_before("SELECT ?", (lo + step,), None)
                elif not self._delete_oldest_events():
                    break  # nothing left that may go
            count, free = self._pages()
            fixed = self.max_bytes - self.wal_budget
            if count * self.page_size > 1.05 * fixed and free:
                # The file is larger than the limit allows (a lower limit than
                # last time): give the free pages back, a little at a time.
                chunk = max(1, self.wal_budget // 4 // self.page_size)
                while free > 0 and count * self.page_size > fixed:
                    self.db.execute(f"PRAGMA incremental_vacuum({chunk})").fetchall()
                    self._checkpoint()
                    count, free = self._pages()
        self.trimmed += deleted
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
            kept_time = self.db.execute("SELECT time_utc FROM samples WHERE id >= ? "
                                        "ORDER BY id LIMIT 1", (first_kept,)).fetchone()
            limit = cutoff if cutoff is not None else (
                kept_time[0] if kept_time else math.inf)
            on_change = self.db.execute("SELECT 1 FROM hub_changes LIMIT 1").fetchone()
            for did, ch in self.db.execute(
                    "SELECT device_id, channel FROM channels WHERE device_id IN "
                    "(SELECT id FROM devices WHERE type = 'hub')").fetchall() if on_change else ():
                self.db.execute("DELETE FROM hub_changes WHERE device_id = ? AND channel = ? "
                                "AND time_utc < ? AND sample_id < ?",
                                (did, ch, limit, first_kept))
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


def _creating(path: Path, pid: int) -> Path:
    """Where process ``pid`` makes the database ``path`` before linking it in."""
    return path.with_name(f".{path.name}.{pid}.creating")


def _remove_stale_creations(path: Path) -> None:
    """Delete what a process killed (SIGKILL, power loss) while making
    ``path`` left beside it: ``.NAME.PID.creating`` files whose PID is no
    longer running. A file of a running process is its own business."""
    prefix, suffix = f".{path.name}.", ".creating"
    try:
        names = [p.name for p in path.parent.iterdir()
                 if p.name.startswith(prefix) and p.name.endswith(suffix)]
    except OSError:
        return
    for name in names:
        pid = name[len(prefix):-len(suffix)]
        if not pid.isdigit() or int(pid) == os.getpid():
            continue
        try:
            os.kill(int(pid), 0)
            continue  # running
        except ProcessLookupError:
            pass
        except (PermissionError, OverflowError):
            continue  # another user's process, or no PID at all: not ours to judge
        with contextlib.suppress(OSError):
            (path.parent / name).unlink()


def _create(path: Path) -> None:
    """A new database appears whole: made beside ``path`` with its schema,
    then linked into place (a process killed meanwhile leaves no half-made
    file at ``path``; what it leaves beside it, the next open removes)."""
    tmp = _creating(path, os.getpid())
    try:
        con = sqlite3.connect(tmp, isolation_level=None)
        try:
            con.execute(f"PRAGMA page_size = {PAGE_SIZE}")
            con.execute("PRAGMA auto_vacuum = INCREMENTAL")
            con.execute("BEGIN")
            for stmt in _statements(_SCHEMA):
                con.execute(stmt)
            con.executemany("INSERT OR REPLACE INTO meta VALUES (?, ?)", [
                ("schema_version", str(SCHEMA_VERSION)), ("pymb_version", __version__)])
            con.execute("COMMIT")
        finally:
            con.close()
        try:
            os.link(tmp, path)  # fails if another process made it meanwhile: use theirs
        except FileExistsError:
            pass
        except OSError:  # no hard links here (a FAT SD card)
            if not path.exists():
                os.replace(tmp, path)
    finally:
        with contextlib.suppress(OSError):
            tmp.unlink()


def _statements(script: str) -> list[str]:
    """An SQL script as its statements (no trigger bodies here: split at ';')."""
    out, buf = [], ""
    for part in script.split(";"):
        buf += part + ";"
        if sqlite3.complete_statement(buf):
            if buf.strip(" \n;"):
                out.append(buf)
            buf = ""
    return out


# -- reading back -----------------------------------------------------------------------


class _Decoder:
    """Decodes rows of ``samples`` (format 2), with the device rows cached."""

    def __init__(self, db: sqlite3.Connection) -> None:
        self.db = db
        self.devices: dict[int, tuple[DeviceInfo, list[float]]] = {}

    def device(self, did: int) -> tuple[DeviceInfo, list[float]]:
        """The device row as the logger's DeviceInfo, and (hub) the humidity
        unit of each channel."""
        got = self.devices.get(did)
        if got is None:
            bus, port, kind, address, name, channels = self.db.execute(
                "SELECT bus, port, type, address, name, channels FROM devices WHERE id = ?",
                (did,)).fetchone()
            units: list[float] = []
            if kind == "hub":
                units = [0.1 if t else 1.0 for (t,) in self.db.execute(
                    "SELECT humidity_tenths FROM channels WHERE device_id = ? ORDER BY channel",
                    (did,))]
            unit: float | tuple[float, ...] = (
                units[0] if len(set(units)) == 1 else tuple(units)) if units else 0.1
            info = DeviceInfo(bus, port, kind, address, name, channels, unit)
            got = self.devices[did] = (info, units)
        return got

    def hub(self, did: int, channels: int, units: Any, t: float, sid: int,
            registers: bytes | None, unsupported: int) -> HubReading:
        if registers is not None:
            regs = _host_words(registers)
            present = None
        else:
            regs = array("H", bytes(2 * HUB.count))
            present = []
            rows = self.db.execute(
                f"SELECT channel, registers FROM hub_changes WHERE device_id = ? AND channel IN "
                f"({', '.join(str(c) for c in range(1, channels + 1))}) AND time_utc = ? "
                f"AND sample_id = ?", (did, t, sid)).fetchall()
            for ch, blob in rows:
                words = _host_words(blob)
                for b in range(len(HUB.blocks)):
                    regs[b * HUB.channels + ch - 1] = words[b]
                present.append(ch - 1)
        names = [b.name for b in HUB.blocks if unsupported >> b.index & 1]
        r = decode_hub(regs, units, channels=channels, unsupported=names)
        if present is not None:
            keep = set(present)
            for b in range(len(HUB.blocks)):
                for ch in range(channels):
                    if ch not in keep:
                        r.values[b * channels + ch] = math.nan
                        r.raw_states[b * channels + ch] = State.NOT_READ
        return r


def _host_words(blob: bytes) -> array[int]:
    a = array("H", blob)
    if sys.byteorder == "little":
        a.byteswap()
    return a


def _connect(db: sqlite3.Connection | str | os.PathLike[str]) -> tuple[sqlite3.Connection, bool]:
    if isinstance(db, sqlite3.Connection):
        return db, False
    p = Path(db)
    if not p.is_file():
        raise InvalidArgument(f"no such database: {db}")
    return sqlite3.connect(f"{p.resolve().as_uri()}?mode=ro", uri=True), True


def samples_after(db: sqlite3.Connection | str | os.PathLike[str], sample_id: int,
                  limit: int = 1000, before: int | None = None) -> list[StoredSample]:
    """Committed samples with an id above ``sample_id`` (and below ``before``),
    in id order, at most ``limit``, decoded (the reader of a store-and-forward
    publisher: keep the last id sent as the cursor). ``db`` is an open
    connection or a path (opened read-only). Only format 2; format 1 raises
    InvalidArgument."""
    con, own = _connect(db)
    try:
        if schema_version(con) != SCHEMA_VERSION:
            raise InvalidArgument("samples_after reads pymb databases of format "
                                  f"{SCHEMA_VERSION} only")
        if before is None:
            return list(_iter_samples(con, "s.id > ?", (sample_id,), limit))
        return list(_iter_samples(con, "s.id > ? AND s.id < ?", (sample_id, before), limit))
    finally:
        if own:
            con.close()


def _iter_samples(con: sqlite3.Connection, where: str, args: Sequence[Any],
                  limit: int | None = None) -> Iterator[StoredSample]:
    dec = _Decoder(con)
    q = ("SELECT s.id, s.device_id, s.time_utc, s.monotonic, s.registers, s.unsupported "
         f"FROM samples s WHERE {where} ORDER BY s.id" + ("" if limit is None else " LIMIT ?"))
    for sid, did, t, mono, blob, unsupported in con.execute(
            q, (*args, limit) if limit is not None else tuple(args)).fetchall():
        info, units = dec.device(did)
        data: HubReading | CoolProTelemetry
        if info.type == "hub":
            data = dec.hub(did, info.channels, units, t, sid, blob, unsupported)
        else:
            regs = _host_words(blob)
            vin, iin, vout, iout, temp, uptime, status = _native.coolpro_telemetry(regs)
            data = CoolProTelemetry(vin, iin, vout, iout, temp, uptime, CoolProStatus(status),
                                    regs)
        yield StoredSample(info, t, mono, data, sid)


# -- text formats ---------------------------------------------------------------------

CSV_COLUMNS = ["time_utc", "time", "bus", "device", "type", "address", "channel", "quantity",
               "value", "state"]


def _iso(t: float) -> str:
    """Seconds since the epoch as ISO 8601 UTC with microseconds (``...Z``)."""
    return time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(t)) + f".{int(t % 1 * 1e6):06d}Z"


def csv_head(t: float, bus: str, device: str | None, kind: str | None,
             address: int | None) -> list[Any]:
    """The first columns of every CSV row (CSV_COLUMNS): time, ISO time, bus,
    device, type, address; "" for what an event has no device for. The one
    home of the row layout, for the CSV sink and for ``pymb export``."""
    return [f"{t:.6f}", _iso(t), bus, device or "", kind or "", "" if address is None else address]


def csv_value(v: float | None) -> Any:
    """A value cell: "" for no value (None or NaN)."""
    return "" if v is None or v != v else v


def sample_rows(sample: Sample) -> Iterator[list[Any]]:
    """A sample as long-format rows: one per quantity (a hub's channel by
    channel); the rows of the CSV sink and of ``pymb export``. A hub value that was not read
    (``not_read``: a channel an ``--on-change`` sample did not store) has no
    row; a "negative zero" is written 0.0."""
    d = sample.device
    head = csv_head(sample.time_utc, d.bus, d.name, d.type, d.address)
    data = sample.data
    if isinstance(data, HubReading):
        c = data.channels
        vals = data.values.tolist()
        sts = data.raw_states.tolist()
        for ch in range(c):
            for b, name in enumerate(_HUB_FIELDS):
                i = b * c + ch
                if sts[i] != _NOT_READ:
                    yield [*head, ch + 1, name, csv_value(vals[i] + 0.0), STATE_NAMES[sts[i]]]
    else:
        for name, v in telemetry_values(data).items():
            yield [*head, "", name, csv_value(v), "value"]


def sample_dict(sample: Sample) -> dict[str, Any]:
    """A sample as one JSON-ready object (None for no value): the line of
    ``--format jsonl`` and, for a sample read back from the database
    (:class:`StoredSample`), with its id as ``sample``, the payload of the
    MQTT plain profile. ``values`` and the rest come from
    :func:`pymb.devices.readings.reading_dict`."""
    d = sample.device
    out: dict[str, Any] = {"time_utc": sample.time_utc, "time": _iso(sample.time_utc),
                           "monotonic": sample.monotonic, "bus": d.bus, "device": d.name,
                           "type": d.type, "address": d.address}
    if isinstance(sample, StoredSample):
        out["sample"] = sample.id
    out.update(reading_dict(sample.data))
    return out


def event_dict(e: Event) -> dict[str, Any]:
    """An event as a JSON-ready object."""
    return {"time_utc": e.time_utc, "time": _iso(e.time_utc), "event": e.kind, "bus": e.bus,
            "device": None if e.device is None else e.device.name, "code": e.code,
            "message": e.message}


class _TextSink:
    keeps_samples = False  #: see :class:`Sink`
    f: IO[str]

    def __init__(self, path: str) -> None:
        self.path = path
        self._own = path != "-"
        try:
            self.f = (open(path, "a", encoding="utf-8", newline="")  # noqa: SIM115
                      if self._own else sys.stdout)
        except OSError as e:
            raise InvalidArgument(f"cannot open {path}: {e.strerror}") from None

    def _failed(self, e: OSError) -> Exception:
        """The error to raise for a failed write: stdout's reader going away
        (``pymb log --out - | head``) stays a BrokenPipeError, which the
        command line ends quietly with 141 as Unix tools do; anything else is
        an OutputError."""
        if isinstance(e, BrokenPipeError) and not self._own:
            return e
        return OutputError(f"cannot write to {self.path}: {e.strerror}")

    def commit(self) -> None:
        try:
            self.f.flush()
        except OSError as e:
            raise self._failed(e) from None

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
            raise self._failed(e) from None

    def event(self, e: Event) -> None:
        try:
            self._event(e)
        except OSError as err:
            raise self._failed(err) from None

    def _event(self, e: Event) -> None:
        d = e.device
        head = (csv_head(e.time_utc, e.bus, None, None, None) if d is None else
                csv_head(e.time_utc, e.bus, d.name, d.type, d.address))
        self.w.writerow([*head, "", f"event:{e.kind}", "" if e.code is None else e.code,
                         e.message])


class JsonlSink(_TextSink):
    """JSON Lines: one object per sample or event."""

    def write(self, sample: Sample) -> None:
        try:
            self.f.write(json.dumps(sample_dict(sample), allow_nan=False) + "\n")
        except OSError as e:
            raise self._failed(e) from None

    def event(self, e: Event) -> None:
        try:
            self.f.write(json.dumps(event_dict(e)) + "\n")
        except OSError as err:
            raise self._failed(err) from None


FORMATS = ("sqlite", "csv", "jsonl", "influx")


def open_sink(fmt: str, path: str, *, max_bytes: int | None = None,
              max_age: float | None = None, on_change: OnChange | None = None) -> Sink:
    """A sink of format ``sqlite``, ``csv``, ``jsonl`` or ``influx`` at ``path``
    (``-``: stdout)."""
    if fmt == "sqlite":
        if path == "-":
            raise InvalidArgument(
                "SQLite needs a file; use --format csv, jsonl or influx for stdout")
        return SqliteSink(path, max_bytes=max_bytes, max_age=max_age, on_change=on_change)
    if on_change is not None:
        raise InvalidArgument("--on-change needs the SQLite format")
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
    """Write a pymb SQLite database (format 1 or 2) out as long-format CSV;
    returns rows."""
    if not Path(db_path).exists():
        raise InvalidArgument(f"no such database: {db_path}")
    # A URI, escaped: '%', '#' and '?' in a file name are the file name's.
    db = sqlite3.connect(Path(db_path).resolve().as_uri() + "?mode=ro", uri=True)
    try:
        version = schema_version(db)
        if version not in (1, SCHEMA_VERSION):
            raise InvalidArgument(f"{db_path} is not a pymb database this pymb can read")
        w = csv.writer(out)
        w.writerow(CSV_COLUMNS)
        if version == 1:
            rows = _export_v1(db, w, device, since)
        else:
            rows = _export_v2(db, w, device, since)
        if events:
            q = ("SELECT e.time_utc, e.bus, d.name, d.type, d.address, e.kind, e.code, e.message "
                 "FROM events e LEFT JOIN devices d ON d.id = e.device_id")
            ew, eargs = _filters(device, since, table="e")
            for r in db.execute(q + ew + " ORDER BY e.id", eargs):
                w.writerow([*csv_head(r[0], r[1], r[2], r[3], r[4]), "", f"event:{r[5]}",
                            "" if r[6] is None else r[6], r[7]])
                rows += 1
        return rows
    except sqlite3.Error as e:
        raise InvalidArgument(f"{db_path} is not a readable pymb database: {e}") from None
    finally:
        db.close()


def _export_v2(db: sqlite3.Connection, w: Any, device: str | None,
               since: float | None) -> int:
    parts: list[str] = ["1"]
    args: list[Any] = []
    if device is not None:
        parts.append("s.device_id IN (SELECT id FROM devices WHERE name = ?)")
        args.append(device)
    if since is not None:
        parts.append("s.time_utc >= ?")
        args.append(since)
    rows = 0
    last = 0
    while True:  # in chunks: a long file never sits in memory
        chunk = list(_iter_samples(db, " AND ".join([*parts, "s.id > ?"]), (*args, last), 500))
        if not chunk:
            return rows
        for s in chunk:
            for row in sample_rows(s):
                w.writerow(row)
                rows += 1
        last = chunk[-1].id


def _export_v1(db: sqlite3.Connection, w: Any, device: str | None,
               since: float | None) -> int:
    """Format 1 (pymb before format 2): decoded tables ``coolpro`` and ``hub``."""
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
            head = csv_head(r[0], r[1], r[2], r[3], r[4])
            n = len(fields)
            for i, name in enumerate(fields):
                state = STATE_NAMES[r[6 + n + i]] if hub else "value"
                w.writerow([*head, "" if r[5] is None else r[5], name, csv_value(r[6 + i]),
                            state])
                rows += 1
    return rows


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
