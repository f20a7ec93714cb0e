"""``pymb export``'s library side: a database (format 1 or 2) as CSV, long
(one row per value) or wide (one row per sample, a column per value)."""

from __future__ import annotations

import csv
import sqlite3
from collections.abc import Iterable, Mapping, Sequence
from typing import IO, Protocol

from pymb.devices.readings import STATE_NAMES
from pymb.errors import InvalidArgument
from pymb.maps import Map
from pymb.store.reader import map_columns
from pymb.store.readonly import reading
from pymb.store.records import reading_values
from pymb.store.schema import COOLPRO_FIELDS, HUB_FIELDS, SCHEMA_VERSION, schema_version
from pymb.store.series import chunks, sample_filter
from pymb.store.text import CSV_COLUMNS, Cell, csv_head, csv_value, sample_rows

__all__ = ["LAYOUTS", "WIDE_HEAD", "export_csv"]

LAYOUTS = ("long", "wide")
#: The wide layout's first columns (then one per value).
WIDE_HEAD = CSV_COLUMNS[:6]


class _Rows(Protocol):
    """Where the rows go: a :func:`csv.writer`."""

    def writerow(self, row: Iterable[Cell], /) -> object:
        """Write one row."""
        ...


def export_csv(db_path: str, out: IO[str], *, device: str | None = None,
               since: float | None = None, until: float | None = None,
               channels: Sequence[int] | None = None, quantities: Sequence[str] | None = None,
               events: bool = False, layout: str = "long",
               maps: Mapping[str, Map] | None = None) -> int:
    """Write a pymb SQLite database out as CSV; returns the rows written.

    ``device`` (a name), ``since`` (included) and ``until`` (excluded, UTC
    seconds), ``channels`` (a hub's; rows without a channel are left out) and
    ``quantities`` choose what goes out. ``layout`` ``long``: one row per
    value, with its state (format 1 or 2); ``wide``: one row per sample and a
    column per value, ``QUANTITY`` for a CoolPro, ``QUANTITY_CHANNEL`` for a
    hub (format 2). A map device is decoded by the copy of its map that the
    database stored, or by the map of the same id in ``maps``
    (``pymb export --map FILE``: a corrected scale, say)."""
    if layout not in LAYOUTS:
        raise InvalidArgument(f"layout must be one of {', '.join(LAYOUTS)}, got {layout!r}")
    if events and layout == "wide":
        raise InvalidArgument("--events is for the long layout (an event is no sample)")
    with reading(db_path) as db:
        version = schema_version(db)
        if version not in (1, SCHEMA_VERSION):
            raise InvalidArgument(f"{db_path} is not a pymb database this pymb can read")
        w = csv.writer(out)
        keep = _Keep(channels, quantities)
        if layout == "wide":
            if version != SCHEMA_VERSION:
                raise InvalidArgument(f"the wide layout reads databases of format "
                                      f"{SCHEMA_VERSION}; {db_path} is of format {version}")
            return _export_wide(db, w, device, since, until, keep, maps)
        w.writerow(CSV_COLUMNS)
        if version == 1:
            rows = _export_v1(db, w, device, since, until, keep)
        else:
            rows = 0
            where, args = sample_filter(device, since, until)
            for s in chunks(db, where, args, given=maps):
                for row in sample_rows(s):
                    if keep.row(row):
                        w.writerow(row)
                        rows += 1
        if events:
            q = ("SELECT e.time_utc, e.bus, d.name, d.type, d.address, e.kind, e.code, e.message "
                 "FROM events e LEFT JOIN devices d ON d.id = e.device_id")
            ew, eargs = sample_filter(device, since, until, table="e")
            for r in db.execute(f"{q} WHERE {ew} ORDER BY e.id", eargs):
                w.writerow([*csv_head(r[0], r[1], r[2], r[3], r[4]), "", f"event:{r[5]}",
                            "" if r[6] is None else r[6], r[7]])
                rows += 1
        return rows


class _Keep:
    """Which values go out: the chosen channels and quantities."""

    def __init__(self, channels: Sequence[int] | None, quantities: Sequence[str] | None) -> None:
        self.channels = None if channels is None else set(channels)
        self.quantities = None if quantities is None else list(quantities)

    def value(self, channel: Cell, quantity: Cell) -> bool:
        if self.quantities is not None and quantity not in self.quantities:
            return False
        return self.channels is None or channel in self.channels

    def row(self, row: Sequence[Cell]) -> bool:
        return self.value(row[6] if row[6] != "" else None, row[7])


def _export_wide(db: sqlite3.Connection, w: _Rows, device: str | None, since: float | None,
                 until: float | None, keep: _Keep, maps: Mapping[str, Map] | None) -> int:
    points = map_columns(db, device, maps)
    cols = [c for c, p in points.items() if keep.value(
        int(c.rsplit("_", 1)[1]) if p.block else None, p.name)]
    if not cols and points:
        raise InvalidArgument("no value to export: the --channel and --quantity chosen match "
                              "nothing these devices have")
    index = {c: i for i, c in enumerate(cols)}
    w.writerow([*WIDE_HEAD, *cols])
    rows = 0
    where, args = sample_filter(device, since, until)
    for s in chunks(db, where, args, given=maps):
        d = s.device
        cells: list[Cell] = [""] * len(cols)
        # A sample with none of the chosen values has no row (an --on-change
        # sample may hold none of the chosen channels).
        stored = False
        for ch, name, v, _ in reading_values(s.data):
            i = index.get(name if ch is None else f"{name}_{ch}")
            if i is not None:
                cells[i] = csv_value(v)
                stored = True
        if stored:
            w.writerow([*csv_head(s.time_utc, d.bus, d.name, d.type, d.address), *cells])
            rows += 1
    return rows


def _export_v1(db: sqlite3.Connection, w: _Rows, device: str | None, since: float | None,
               until: float | None, keep: _Keep) -> int:
    """Format 1 (pymb before format 2): decoded tables ``coolpro`` and ``hub``."""
    rows = 0
    where, args = sample_filter(device, since, until)
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
        q = f"{sql.format(cols=cols)} WHERE {where} ORDER BY s.id" + (", h.channel" if hub else "")
        for r in db.execute(q, args):
            head = csv_head(r[0], r[1], r[2], r[3], r[4])
            n = len(fields)
            for i, name in enumerate(fields):
                if not keep.value(r[5], name):
                    continue
                state = STATE_NAMES[r[6 + n + i]] if hub else "value"
                w.writerow([*head, "" if r[5] is None else r[5], name, csv_value(r[6 + i]),
                            state])
                rows += 1
    return rows

