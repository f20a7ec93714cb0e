"""Reading back: stored samples decoded again (format 2)."""

from __future__ import annotations

import math
import os
import sqlite3
from array import array
from collections.abc import Iterator, Mapping, Sequence
from typing import Any

from pymb import maps
from pymb.devices import CoolProTelemetry, HubReading, State, decode_hub
from pymb.devices.coolpro import decode_telemetry
from pymb.devices.mapreading import MapReading, group_layout, group_points
from pymb.errors import InvalidArgument
from pymb.maps import Decoder, Map, Point, Value
from pymb.store.readonly import open_readonly
from pymb.store.records import DeviceInfo, StoredSample
from pymb.store.schema import (
    HUB_FIELDS,
    HUB_STRIDE,
    MAP_UNSUPPORTED_BITS,
    SCHEMA_VERSION,
    host_words,
    parse_layout_key,
    schema_version,
)

__all__ = ["iter_samples", "map_columns", "map_point_names", "samples_after", "stored_map"]


def stored_map(db: sqlite3.Connection, kind: str, layout: str = "",
               given: Mapping[str, Map] | None = None) -> tuple[Map, str | None] | None:
    """The map a database stored for device type ``kind``, with the options
    of a devices row's ``layout`` key (its humidity_units), and the group of
    that row; None if the database has no map of that id. A map in ``given``
    (``pymb export --map FILE``) is used instead of the stored copy."""
    group, options = parse_layout_key(layout) if layout else (None, {})
    if given and kind in given:
        m = given[kind]
        return (m.configure(options) if options else m), group
    row = db.execute("SELECT source FROM maps WHERE id = ?", (kind,)).fetchone() if \
        db.execute("SELECT 1 FROM sqlite_master WHERE name = 'maps'").fetchone() else None
    if row is None:
        return None
    m = maps.loads(row[0], source=f"map {kind} (stored)")
    return (m.configure(options) if options else m), group


def map_columns(db: sqlite3.Connection, device: str | None = None,
                given: Mapping[str, Map] | None = None) -> dict[str, Point]:
    """The wide layout's columns of the map devices in a database (of one
    ``device``, by name): a point name, or ``name_N`` for channel N of a
    block, in the order of each map's points -> the point."""
    q = ("SELECT type, humidity_units FROM devices WHERE type NOT IN ('coolpro', 'hub')"
         + (" AND name = ?" if device else "") + " ORDER BY id")
    cols: dict[str, Point] = {}
    for kind, layout in db.execute(q, (device,) if device else ()).fetchall():
        got = stored_map(db, kind, layout, given)
        if got is None:
            continue
        m, group = got
        for n in group_points(m, group):
            p = m.points[n]
            for c in range(1, p.channels + 1) if p.block else (0,):
                cols.setdefault(f"{n}_{c}" if c else n, p)
    return cols


def map_point_names(path: str, given: Mapping[str, Map] | None = None) -> list[str]:
    """The point names of the map devices a database at ``path`` holds (by
    their stored maps, or the ones in ``given``), in the maps' order."""
    db = open_readonly(path)
    try:
        return list(dict.fromkeys(p.name for p in map_columns(db, None, given).values()))
    finally:
        db.close()


class _Decoder:
    """Decodes rows of ``samples`` (format 2), with the device rows cached."""

    def __init__(self, db: sqlite3.Connection, given: Mapping[str, Map] | None = None) -> None:
        self.db = db
        self.given = given
        self.devices: dict[int, tuple[DeviceInfo, list[float]]] = {}
        self.maps: dict[int, tuple[Map, str | None, list[Decoder], list[str]]] = {}

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

    def map_reading(self, did: int, info: DeviceInfo, blob: bytes, unsupported: int
                    ) -> MapReading:
        """A map device's stored group, decoded again by its stored map."""
        got = self.maps.get(did)
        if got is None:
            (units,) = self.db.execute("SELECT humidity_units FROM devices WHERE id = ?",
                                       (did,)).fetchone()
            found = stored_map(self.db, info.type, units, self.given)
            if found is None:
                raise InvalidArgument(f"the database has no map {info.type!r} for device "
                                      f"{info.name}")
            m, group = found
            got = self.maps[did] = (m, group, group_layout(m, group), group_points(m, group))
        m, group, layout, names = got
        regs = host_words(blob)
        values: dict[str, Value] = {}
        states: dict[str, Any] = {}
        at = 0
        for dec in layout:
            b = dec.decode(regs[at:at + dec.count])
            values.update(dec.values(b))
            states.update(dec.states(b))
            at += dec.count
        gone: list[str] = []
        if unsupported:
            for i, n in enumerate(names):
                if unsupported >> min(i, MAP_UNSUPPORTED_BITS) & 1:
                    gone.append(n)
                    v = values[n]
                    if isinstance(v, list):
                        values[n], states[n] = [None] * len(v), ["unsupported"] * len(v)
                    else:
                        values[n], states[n] = None, "unsupported"
        out = {n: values[n] for n in names}
        return MapReading(m, group, out, {n: states[n] for n in names}, regs, tuple(gone))

    def hub(self, did: int, channels: int, units: Any, t: float, sid: int,
            registers: bytes | None, unsupported: int) -> HubReading:
        if registers is not None:
            regs = host_words(registers)
            present = None
        else:
            regs = array("H", bytes(2 * HUB_STRIDE * len(HUB_FIELDS)))
            present = []
            rows = self.db.execute(
                f"SELECT channel, registers FROM hub_changes WHERE device_id = ? AND channel IN "
                f"({', '.join(str(c) for c in range(1, channels + 1))}) AND time_utc = ? "
                f"AND sample_id = ?", (did, t, sid)).fetchall()
            for ch, blob in rows:
                words = host_words(blob)
                for b in range(len(HUB_FIELDS)):
                    regs[b * HUB_STRIDE + ch - 1] = words[b]
                present.append(ch - 1)
        names = [n for b, n in enumerate(HUB_FIELDS) if unsupported >> b & 1]
        r = decode_hub(regs, units, channels=channels, unsupported=names)
        if present is not None:
            keep = set(present)
            for b in range(len(HUB_FIELDS)):
                for ch in range(channels):
                    if ch not in keep:
                        r.values[b * channels + ch] = math.nan
                        r.raw_states[b * channels + ch] = State.NOT_READ
        return r



def _connect(db: sqlite3.Connection | str | os.PathLike[str]) -> tuple[sqlite3.Connection, bool]:
    if isinstance(db, sqlite3.Connection):
        return db, False
    return open_readonly(db), True


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
            return list(iter_samples(con, "s.id > ?", (sample_id,), limit))
        return list(iter_samples(con, "s.id > ? AND s.id < ?", (sample_id, before), limit))
    finally:
        if own:
            con.close()


def iter_samples(con: sqlite3.Connection, where: str, args: Sequence[Any],
                  limit: int | None = None, given: Mapping[str, Map] | None = None
                  ) -> Iterator[StoredSample]:
    """The samples ``where`` says, decoded (map devices by their stored map,
    or by the one in ``given``)."""
    dec = _Decoder(con, given)
    q = ("SELECT s.id, s.device_id, s.time_utc, s.monotonic, s.registers, s.unsupported "
         f"FROM samples s WHERE {where} ORDER BY s.id" + ("" if limit is None else " LIMIT ?"))
    for sid, did, t, mono, blob, unsupported in con.execute(
            q, (*args, limit) if limit is not None else tuple(args)).fetchall():
        info, units = dec.device(did)
        data: HubReading | CoolProTelemetry | MapReading
        if info.type == "hub":
            data = dec.hub(did, info.channels, units, t, sid, blob, unsupported)
        elif info.type != "coolpro":
            data = dec.map_reading(did, info, blob, unsupported)
        else:
            regs = host_words(blob)
            data = decode_telemetry(regs)
        yield StoredSample(info, t, mono, data, sid)
