"""The SQLite format: its tables, and the views that decode the stored
registers in plain SQL (generated from the device maps)."""

from __future__ import annotations

import hashlib
import math
import sqlite3
from collections.abc import Sequence
from pathlib import Path

from pymb import __version__, maps
from pymb.devices import State
from pymb.devices.mapreading import group_points
from pymb.devices.readings import STATE_NAMES
from pymb.errors import InvalidArgument
from pymb.maps import Map, Point
from pymb.wire import registers_from_wire, registers_to_wire

__all__ = [
    "COOLPRO_FIELDS",
    "FORMAT1_LAYOUT",
    "HUB_FIELDS",
    "HUB_STRIDE",
    "MAP_UNSUPPORTED_BITS",
    "MIN_BYTES",
    "PAGE_SIZE",
    "SCHEMA",
    "SCHEMA_SQL",
    "SCHEMA_VERSION",
    "SqlArg",
    "host_words",
    "install",
    "map_layout_key",
    "new_file",
    "open_format",
    "parse_layout_key",
    "schema_version",
    "statements",
    "unsupported_mask",
    "wire_bytes",
]

# The hub and the CoolPro as their maps say, with a channel's humidity in 0.1 % and in 1 %.
_HUB_TENTHS, _HUB_ONE = (maps.builtin("hub").configure(humidity_unit=u) for u in (0.1, 1))
_COOLPRO = [p for p in maps.builtin("coolpro").points.values() if p.group == "telemetry"]
#: a CoolPro sample's quantities: its map's telemetry points
COOLPRO_FIELDS = [p.name for p in _COOLPRO]
#: a hub sample's quantities: its map's blocks, one per quantity
HUB_FIELDS = list(_HUB_TENTHS.points)
#: registers of a block in a stored hub sweep: a channel's register of block
#: k is at ``k * HUB_STRIDE + channel - 1`` whatever the channels logged
HUB_STRIDE = _HUB_TENTHS.points[HUB_FIELDS[0]].channels
#: the device types the writer keeps in format 1's layout (the two devices
#: format 1 knew): no ``maps`` row (the reader takes the shipped map of a
#: type with none), a hub's channels and humidity units in its ``devices``
#: row and its ``--on-change`` samples by channel in ``hub_changes``
FORMAT1_LAYOUT = frozenset({"coolpro", "hub"})



#: Registers are stored as they travel, big-endian 16-bit words: the wire's
#: own conversions, to the stored bytes and back to an array of registers.
wire_bytes = registers_to_wire
host_words = registers_from_wire


# -- map devices ---------------------------------------------------------------------

#: bits of ``samples.unsupported`` for a map reading's points: bit i is the
#: group's i-th point; the last bit stands for it and every point after it
MAP_UNSUPPORTED_BITS = 62


def map_layout_key(group: str | None, options: tuple[tuple[str, float], ...]) -> str:
    """What a map device's ``devices.humidity_units`` holds: the group its
    samples read (``group=fast``; ``group=`` for every readable point) and
    the map options it was read with (``,channels=50``)."""
    return f"group={group or ''}" + "".join(f",{k}={v:g}" for k, v in options)


def parse_layout_key(text: str) -> tuple[str | None, dict[str, float]]:
    """(group, options) of :func:`map_layout_key`'s text."""
    head, *opts = text.split(",")
    group = head.partition("=")[2] or None
    options = {}
    for o in opts:
        k, _, v = o.partition("=")
        options[k] = float(v)
    return group, options


def unsupported_mask(m: Map, group: str | None, names: Sequence[str]) -> int:
    """``samples.unsupported`` of a map reading whose ``names`` were refused."""
    index = {n: i for i, n in enumerate(group_points(m, group))}
    mask = 0
    for n in names:
        mask |= 1 << min(index[n], MAP_UNSUPPORTED_BITS)
    return mask


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
#                unit of each (1: 0.1 %, 0: 1 %). A map device has a row per polling
#                group, its humidity_units saying which (map_layout_key).
#   maps         a map device's map (its pymb.map/1 text), by its id: a map device's
#                samples hold the registers of one group, each of its tables from the
#                group's first register to its last, one table after the other; its
#                unsupported column has a bit per point of the group the device refused.
#                A device with no map row (the hub, the CoolPro: format 1's layout) is
#                decoded by the shipped map of its type, configured by its devices row
#                (its channels and their humidity units), for the map's first group; a
#                row with channels stores an --on-change sample by channel (hub_changes).
#   events       faults, reconnects, trimming.
#
# Decoded values are views, in plain SQL (no extension; Debian 12's sqlite3 3.40):
# hub_readings / hub and coolpro_readings / coolpro, with the same columns as the tables
# of format 1. The decoding rules of the C core are written out in SQL below, generated
# from the device maps, and tested value by value against the C decoder.

SCHEMA_VERSION = 2

#: What a statement's ``?`` takes: SQLite's own types.
SqlArg = int | float | str | bytes | None
#: a new database's page size. A commit writes whole pages to the WAL (the
#: last of the samples, their parent, the time index's last page, the
#: header), each copied once more at the checkpoint: the
#: smaller the page, the fewer bytes a commit of a few rows writes (2 KB:
#: about half of 4 KB's). A hub sweep (1,400 bytes) still fits a page: at
#: 1 KB it would spill onto overflow pages, whose content nothing of SQLite's
#: checks (a zeroed one passes quick_check and integrity_check, its registers
#: read back as zeros), where a zeroed page of 2 KB is found at the start
#: (pymb.store.damage). A file made with other pages keeps them.
PAGE_SIZE = 2048
WAL_MIN, WAL_MAX = 256 * 1024, 8 * 1024 * 1024
MIN_BYTES = 1_000_000  #: the smallest size bound accepted (schema pages and a WAL budget)

_DIGITS = "'123456789ABCDEF'"  # instr() of a hex digit in this is its value ('0' -> 0)


def _digit(h: str, i: int) -> str:
    return f"instr({_DIGITS}, substr({h}, {i}, 1))"


def _u16(h: str) -> str:
    """The unsigned value of 4 hex digits ``h`` (an SQL expression)."""
    return (f"({_digit(h, 1)} * 4096 + {_digit(h, 2)} * 256 + {_digit(h, 3)} * 16 + "
            f"{_digit(h, 4)})")


def _marker(p: Point, state: str) -> str | None:
    """The raw value that marks ``state`` for point ``p``, as 4 hex digits in SQL."""
    raw = next((r for r, st in p.markers.items() if st == state), None)
    return None if raw is None else f"'{raw:04X}'"


def _scaled(raw: str, scale: float | None) -> str:
    """``raw`` (an SQL expression) times ``scale``, as SQL."""
    if scale is None:
        return raw
    if scale < 1 and math.isclose(1 / scale, round(1 / scale)):
        return f"{raw} / {round(1 / scale)}.0"
    return f"{raw} * {scale:g}.0" if scale == int(scale) else f"{raw} * {scale}"


def _hub_columns() -> tuple[list[str], list[str]]:
    """SQL for the hub's decoded values and states, one pair per block of its
    map; a point whose scale and markers follow the channel's humidity unit
    picks them by ``channels.humidity_tenths``."""
    values, states = [], []
    for k, name in enumerate(HUB_FIELDS):
        p, one = _HUB_TENTHS.points[name], _HUB_ONE.points[name]
        h = (f"hex(CASE WHEN s.registers IS NULL THEN substr(x.registers, {2 * k + 1}, 2)"
             f" ELSE substr(s.registers, {2 * k * HUB_STRIDE + 1} + 2 * (c.channel - 1),"
             f" 2) END)")
        unsupported = f"((s.unsupported >> {k}) & 1)"
        offline = _marker(p, "offline")
        tenths, ones = _marker(p, "no_sensor"), _marker(one, "no_sensor")
        no_sensor = "0" if tenths is None else \
            f"{h} = CASE WHEN c.humidity_tenths THEN {tenths} ELSE {ones} END"
        if p.type == "sm16":
            raw = (f"(CASE WHEN {_digit(h, 1)} >= 8 THEN -1 ELSE 1 END) * (({_digit(h, 1)} % 8)"
                   f" * 4096 + {_digit(h, 2)} * 256 + {_digit(h, 3)} * 16 + {_digit(h, 4)})")
        elif p.type == "i16":
            raw = f"({_u16(h)} - CASE WHEN {_digit(h, 1)} >= 8 THEN 65536 ELSE 0 END)"
        else:
            raw = _u16(h)
        scaled = _scaled(raw, p.scale) if p.scale == one.scale else (
            f"CASE WHEN c.humidity_tenths THEN {_scaled(raw, p.scale)} "
            f"ELSE {_scaled(raw, one.scale)} END")
        values.append(f"CASE WHEN {unsupported} OR {h} = {offline} OR ({no_sensor}) THEN NULL "
                      f"ELSE {scaled} END AS {name}")
        states.append(f"CASE WHEN {unsupported} THEN {int(State.UNSUPPORTED)} "
                      f"WHEN {h} = {offline} THEN {int(State.OFFLINE)} "
                      f"WHEN {no_sensor} THEN {int(State.NO_SENSOR)} "
                      f"ELSE {int(State.VALUE)} END AS {name}_state")
    return values, states


def _state_names() -> list[str]:
    """Each block's state by name (``value``, ``offline``, ...), from its code
    column: the views read without a join on ``states``."""
    cases = " ".join(f"WHEN {int(s)} THEN '{STATE_NAMES[int(s)]}'" for s in State)
    return [f"CASE {n}_state {cases} END AS {n}_state_name" for n in HUB_FIELDS]


def _coolpro_columns() -> list[str]:
    """SQL for the CoolPro's telemetry, by its map: registers from its first point's."""
    first = min(p.address for p in _COOLPRO)
    out = []
    for p in _COOLPRO:
        i = p.address - first

        def word(k: int) -> str:
            return _u16(f"hex(substr(s.registers, {2 * k + 1}, 2))")

        if p.type == "u32":
            lo, hi = (i, i + 1) if p.order == "CDAB" else (i + 1, i)
            expr = f"{word(lo)} + 65536 * {word(hi)}"
        else:
            expr = _scaled(word(i), p.scale)
        out.append(f"{expr} AS {p.name}")
    return out


_HUB_VALUES, _HUB_STATES = _hub_columns()
#: UTC, ISO 8601, marked as such ('Z'), to the millisecond.
_TIME = "strftime('%Y-%m-%dT%H:%M:%fZ', s.time_utc, 'unixepoch')"

SCHEMA = f"""
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
CREATE TABLE IF NOT EXISTS maps(
    id TEXT PRIMARY KEY,   -- a map device's type
    source TEXT NOT NULL); -- the pymb.map/1 file it was read with
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
    SELECT *, {", ".join(_state_names())} FROM (
    SELECT {_TIME} AS time, s.time_utc, d.name AS device, d.address, s.id AS sample_id,
           c.channel, {", ".join(_HUB_VALUES)}, {", ".join(_HUB_STATES)}
      FROM samples s JOIN devices d ON d.id = s.device_id
      JOIN channels c ON c.device_id = s.device_id
      LEFT JOIN hub_changes x ON x.device_id = s.device_id AND x.channel = c.channel
                             AND x.time_utc = s.time_utc AND x.sample_id = s.id
     WHERE s.registers IS NOT NULL OR x.registers IS NOT NULL);
CREATE VIEW hub AS
    SELECT sample_id, channel, {", ".join(HUB_FIELDS)},
           {", ".join(n + "_state" for n in HUB_FIELDS)} FROM hub_readings;
CREATE VIEW coolpro_readings AS
    SELECT {_TIME} AS time, s.time_utc, d.name AS device, d.address, s.id AS sample_id,
           {", ".join(_coolpro_columns())}
      FROM samples s JOIN devices d ON d.id = s.device_id WHERE d.type = 'coolpro';
CREATE VIEW coolpro AS
    SELECT sample_id, {", ".join(COOLPRO_FIELDS)} FROM coolpro_readings;
CREATE VIEW event_log AS
    SELECT strftime('%Y-%m-%dT%H:%M:%fZ', e.time_utc, 'unixepoch') AS time, e.time_utc, e.bus,
           d.name AS device, e.kind, e.code, e.message
      FROM events e LEFT JOIN devices d ON d.id = e.device_id;
"""


#: what identifies the schema above (a digest of its text): a database whose
#: ``meta`` holds it needs no schema statement at open
SCHEMA_SQL = hashlib.sha256(SCHEMA.encode()).hexdigest()[:16]


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


def statements(script: str) -> list[str]:
    """An SQL script as its statements (no trigger bodies here: split at ';')."""
    out, buf = [], ""
    for part in script.split(";"):
        buf += part + ";"
        if sqlite3.complete_statement(buf):
            if buf.strip(" \n;"):
                out.append(buf)
            buf = ""
    return out


def new_file(db: sqlite3.Connection) -> None:
    """The page layout of a new (empty) database: :data:`PAGE_SIZE` pages and
    no pointer-map pages (``auto_vacuum = NONE``: with incremental vacuum
    every commit that adds a page rewrites the pointer-map page that lists
    it, one page more to the WAL; a file under a lower size limit than
    before shrinks by one VACUUM instead, :mod:`pymb.store.retention`).
    A file made otherwise keeps its layout."""
    db.execute(f"PRAGMA page_size = {PAGE_SIZE}")
    db.execute("PRAGMA auto_vacuum = NONE")


def install(db: sqlite3.Connection) -> None:
    """Write the schema, its views and its meta rows into ``db`` (autocommit
    mode), in one transaction: the one set-up of a new or opened database."""
    db.execute("BEGIN IMMEDIATE")
    for stmt in statements(SCHEMA):
        db.execute(stmt)
    db.executemany("INSERT OR REPLACE INTO meta VALUES (?, ?)", [
        ("schema_version", str(SCHEMA_VERSION)), ("pymb_version", __version__),
        ("registers", "big-endian 16-bit words from the device map's first register"),
        ("schema_sql", SCHEMA_SQL),
    ])
    db.executemany("INSERT OR REPLACE INTO states VALUES (?, ?)",
                   [(s.value, s.name.lower()) for s in State])
    db.execute("COMMIT")


def open_format(db: sqlite3.Connection, path: Path, max_bytes: int | None) -> tuple[int, int]:
    """Check that ``db`` (the writer's connection, autocommit) is a pymb
    database of this format or a new one, set it up as the writer uses it
    (WAL, ``synchronous=FULL``, the checkpoint and WAL size from ``max_bytes``)
    and install the schema if it is not there as this pymb writes it.
    Returns ``(page_size, wal_budget)``."""
    version = schema_version(db)
    if version is None:
        raise InvalidArgument(f"{path} is not a pymb database; log to a new file")
    if version not in (0, SCHEMA_VERSION):
        older = version < SCHEMA_VERSION
        raise InvalidArgument(
            f"{path} holds pymb format {version}, this pymb writes format "
            f"{SCHEMA_VERSION}; " + ("log to a new file (pymb export still reads this one)"
                                    if older else "use the newer pymb that wrote it"))
    if version == 0:
        new_file(db)
    mode = db.execute("PRAGMA journal_mode = WAL").fetchone()[0]
    if mode != "wal":
        raise InvalidArgument(f"{path}: cannot use WAL journal mode ({mode})")
    # FULL: a commit is on the disk (the WAL synced) before other connections
    # see it, so the forwarder never publishes a sample a power cut can take
    # back, and no id it published is handed to another sample after one.
    db.execute("PRAGMA synchronous = FULL")
    page_size = int(db.execute("PRAGMA page_size").fetchone()[0])
    wal_budget = WAL_MAX
    if max_bytes is not None:
        wal_budget = max(WAL_MIN, min(WAL_MAX, max_bytes // 16))
    # Checkpoint at half the budget; truncate the WAL file back to it afterwards.
    db.execute(f"PRAGMA wal_autocheckpoint = {max(16, wal_budget // 2 // page_size)}")
    db.execute(f"PRAGMA journal_size_limit = {wal_budget // 2}")
    if version == SCHEMA_VERSION and db.execute(
            "SELECT value FROM meta WHERE key = 'schema_sql'").fetchone() == (SCHEMA_SQL,):
        return page_size, wal_budget  # as this pymb would write it: nothing to write
    install(db)
    return page_size, wal_budget
