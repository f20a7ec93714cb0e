"""``pymb export``'s library side: a database (format 1 or 2) as long-format CSV."""

from __future__ import annotations

import csv
import sqlite3
from collections.abc import Sequence
from typing import IO, Any

from pymb.devices.readings import STATE_NAMES
from pymb.errors import InvalidArgument
from pymb.store.reader import iter_samples
from pymb.store.readonly import open_readonly
from pymb.store.schema import COOLPRO_FIELDS, HUB_FIELDS, SCHEMA_VERSION, schema_version
from pymb.store.text import CSV_COLUMNS, csv_head, csv_value, sample_rows

__all__ = ["export_csv"]


def export_csv(db_path: str, out: IO[str], *, device: str | None = None,
               since: float | None = None, events: bool = False) -> int:
    """Write a pymb SQLite database (format 1 or 2) out as long-format CSV;
    returns rows."""
    try:
        db = open_readonly(db_path)
    except sqlite3.Error as e:
        raise InvalidArgument(f"{db_path} is not a readable pymb database: {e}") from None
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
        chunk = list(iter_samples(db, " AND ".join([*parts, "s.id > ?"]), (*args, last), 500))
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
         COOLPRO_FIELDS),
        ("SELECT s.time_utc, d.bus, d.name, d.type, d.address, h.channel, {cols} FROM hub h "
         "JOIN samples s ON s.id = h.sample_id JOIN devices d ON d.id = s.device_id",
         HUB_FIELDS),
    ):
        hub = fields is HUB_FIELDS
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
