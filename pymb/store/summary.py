"""What a database holds, in a few figures (``pymb info``): its devices and
their samples, the time span, faults by kind, the file and WAL sizes, and
each forwarder's backlog."""

from __future__ import annotations

import math
import os
import sqlite3
from dataclasses import dataclass, field
from pathlib import Path

from pymb.errors import InvalidArgument, ModbusError
from pymb.store.commands import write_counts
from pymb.store.lock import writer_of
from pymb.store.reader import stored_map
from pymb.store.readonly import open_readonly, reading
from pymb.store.records import FAULT_KINDS
from pymb.store.schema import SCHEMA_VERSION, parse_layout_key, schema_version

__all__ = ["DeviceSummary", "Summary", "devices", "event_counts", "summarize"]


@dataclass(frozen=True)
class DeviceSummary:
    """One device of a database and its samples."""

    name: str
    type: str
    address: int
    bus: str
    port: str
    channels: int
    samples: int
    first: float | None  #: UTC seconds of its first sample (None: no sample)
    last: float | None
    #: a map device: its samples by polling group ("" for every point of a map
    #: without groups): every group of its stored map, in the map's order, 0 for
    #: one that never delivered, then any other group logged; empty for the
    #: built-in devices
    groups: tuple[tuple[str, int], ...] = ()


@dataclass(frozen=True)
class Summary:
    """What ``pymb info`` shows of a database."""

    path: str
    schema: int
    pymb_version: str
    devices: list[DeviceSummary]
    samples: int
    first: float | None
    last: float | None
    faults: dict[str, int]  #: fault events by kind (reconnects and the rest are not faults)
    events: dict[str, int]  #: every event by kind
    size: int  #: the database file, bytes
    wal: int  #: its write-ahead log, bytes (0: none)
    backlog: dict[str, int] = field(default_factory=dict)  #: forwarder: samples not yet sent
    #: the process writing the database now (``pymb log, PID 1234``), or None
    writer: str | None = None
    #: points of write commands (applied, refused or failed); (0, 0): none
    writes: tuple[int, int] = (0, 0)


def devices(con: sqlite3.Connection) -> list[tuple[str, str, int, str]]:
    """(name, type, address, bus) of every device of an open database, once
    each (the store keeps a row per configuration, and a map device a row per
    polling group: those are one device)."""
    return [(str(n), str(t), int(a), str(b)) for n, t, a, b in con.execute(
        "SELECT name, type, address, bus FROM devices GROUP BY name, type, address, bus "
        "ORDER BY MIN(id)")]


def event_counts(path: str | os.PathLike[str],
                 leave_out: tuple[str, ...] = ("connect", "reconnect"),
                 since: float = -math.inf) -> list[tuple[str, int]]:
    """(kind, count) of the events of the database at ``path`` recorded at
    ``since`` (UTC seconds) or later, the most frequent first, without the
    kinds in ``leave_out``; read without writing."""
    con = open_readonly(path)  # leaves no -wal or -shm behind
    try:
        marks = ", ".join("?" * len(leave_out)) or "NULL"
        return [(str(k), int(n)) for k, n in con.execute(
            f"SELECT kind, COUNT(*) FROM events WHERE kind NOT IN ({marks}) AND time_utc >= ? "
            "GROUP BY kind ORDER BY 2 DESC", (*leave_out, since))]
    finally:
        con.close()


def summarize(path: str | os.PathLike[str]) -> Summary:
    """The summary of the pymb database at ``path``, read without writing."""
    with reading(path) as con:
        return _summarize(con, str(path))


def _summarize(con: sqlite3.Connection, path: str) -> Summary:
    version = schema_version(con)
    if version not in (1, SCHEMA_VERSION):
        raise InvalidArgument(f"{path} is not a database written by pymb")
    row = con.execute("SELECT value FROM meta WHERE key = 'pymb_version'").fetchone()
    per = {did: (n, f, la) for did, n, f, la in con.execute(
        "SELECT device_id, COUNT(*), MIN(time_utc), MAX(time_utc) FROM samples "
        "GROUP BY device_id")}
    # one device: the rows of its configurations (and of a map device's groups) merged
    merged: dict[tuple[str, str, int, str, str], list[tuple[int, int, str]]] = {}
    for did, name, kind, address, bus, port, channels, units in con.execute(
            "SELECT id, name, type, address, bus, port, channels, humidity_units "
            "FROM devices ORDER BY id"):
        merged.setdefault((name, kind, address, bus, port), []).append((did, channels, units))
    devs = []
    for (name, kind, address, bus, port), rows in merged.items():
        got = [per.get(did, (0, None, None)) for did, _, _ in rows]
        firsts = [f for _, f, _ in got if f is not None]
        lasts = [la for _, _, la in got if la is not None]
        # a map device's samples by group (none for a device without a stored map)
        groups = dict.fromkeys(_map_groups(con, kind), 0)
        for (_, _, units), (n, _, _) in zip(rows, got, strict=True):
            if not units.startswith("group="):
                continue  # the row of an event alone (a timeout): no group of its own
            group = parse_layout_key(units)[0] or ""
            groups[group] = groups.get(group, 0) + n
        devs.append(DeviceSummary(
            name, kind, address, bus, port, rows[-1][1], sum(n for n, _, _ in got),
            min(firsts, default=None), max(lasts, default=None), tuple(groups.items())))
    # The time index answers these two without reading the table.
    (first,) = con.execute("SELECT MIN(time_utc) FROM samples").fetchone()
    (last,) = con.execute("SELECT MAX(time_utc) FROM samples").fetchone()
    events = {str(k): int(n) for k, n in con.execute(
        "SELECT kind, COUNT(*) FROM events GROUP BY kind ORDER BY kind")}
    backlog: dict[str, int] = {}
    if con.execute("SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = 'outbox'"
                   ).fetchone():
        for name, cursor in con.execute("SELECT name, sample_id FROM outbox ORDER BY name"):
            (n,) = con.execute("SELECT COUNT(*) FROM samples WHERE id > ?",
                               (cursor or 0,)).fetchone()
            backlog[str(name)] = int(n)
    wal = Path(f"{path}-wal")
    return Summary(
        path=path, schema=int(version or 0), pymb_version=str(row[0]) if row else "?",
        devices=devs, samples=sum(d.samples for d in devs), first=first, last=last,
        faults={k: n for k, n in events.items() if k in FAULT_KINDS}, events=events,
        size=os.path.getsize(path), wal=wal.stat().st_size if wal.exists() else 0,
        backlog=backlog, writer=writer_of(path), writes=write_counts(con))


def _map_groups(con: sqlite3.Connection, kind: str) -> list[str]:
    """The polling groups of the map stored for device type ``kind`` (empty:
    no map stored, or one without groups)."""
    try:
        got = stored_map(con, kind)
    except (ModbusError, sqlite3.Error):
        return []
    return list(got[0].groups) if got is not None else []
