"""Reading back: stored samples decoded again (format 2)."""

from __future__ import annotations

import dataclasses
import functools
import math
import os
import sqlite3
from array import array
from collections.abc import Iterator, Mapping, Sequence

from pymb import maps
from pymb.devices.hub import blocks_in_other_units
from pymb.devices.hub import units as humidity_units
from pymb.devices.mapreading import Blocks, GroupDecode, MapReading, group_points
from pymb.devices.readings import map_reading, reading_view
from pymb.errors import InvalidArgument
from pymb.maps import Map, MapError, Point
from pymb.maps.types import STATES
from pymb.store.readonly import open_readonly
from pymb.store.records import DeviceInfo, StoredSample
from pymb.store.schema import (
    MAP_UNSUPPORTED_BITS,
    SCHEMA_VERSION,
    SqlArg,
    host_words,
    parse_layout_key,
    schema_version,
)

#: a ``samples`` row: id, device_id, time_utc, monotonic, registers, unsupported
SampleRow = tuple[int, int, float, float, bytes | None, int]
#: a ``hub_changes`` row of a sample: channel (from 1), registers
HubRow = tuple[int, bytes]

__all__ = ["DeviceRow", "HubRow", "RowDecoder", "SampleRow", "device_map", "device_row",
           "has_map", "iter_samples", "map_columns", "map_point_names", "samples_after",
           "shipped_map", "stored_after", "stored_map"]


def stored_map(db: sqlite3.Connection, kind: str, layout: str = "",
               given: Mapping[str, Map] | None = None) -> tuple[Map, str | None] | None:
    """The map a database stored for device type ``kind``, with the options
    of a devices row's ``layout`` key (its humidity_units), and the group of
    that row; None if the database has no map of that id. A map in ``given``
    (``pymb export --map FILE``) is used instead of the stored copy."""
    if given and kind in given:
        return _configured("", kind, layout, given)
    row = db.execute("SELECT source FROM maps WHERE id = ?", (kind,)).fetchone() if \
        db.execute("SELECT 1 FROM sqlite_master WHERE name = 'maps'").fetchone() else None
    return None if row is None else _configured(row[0], kind, layout, given)


def _configured(source: str, kind: str, layout: str,
                given: Mapping[str, Map] | None) -> tuple[Map, str | None]:
    """A stored map's text (or ``given``'s map of ``kind``) configured as a
    devices row's ``layout`` key says, and that row's group."""
    group, options = parse_layout_key(layout) if layout else (None, {})
    m = given[kind] if given and kind in given else \
        maps.loads(source, source=f"map {kind} (stored)")
    return (m.configure(options) if options else m), group


def device_map(db: sqlite3.Connection, kind: str, layout: str, channels: int = 0,
               given: Mapping[str, Map] | None = None) -> tuple[Map, str | None] | None:
    """The map and group of a devices row (type ``kind``, ``humidity_units``
    ``layout``, ``channels``): its stored map (or the one in ``given``), else
    the shipped map of format 1's layout (:func:`shipped_map`); None when
    there is neither."""
    if has_map(db, kind):
        return stored_map(db, kind, layout, given)
    return shipped_map(kind, channels)


def map_columns(db: sqlite3.Connection, device: str | None = None,
                given: Mapping[str, Map] | None = None) -> dict[str, Point]:
    """The wide layout's columns of the devices in a database (of one
    ``device``, by name) -> their points: a point name, or ``name_N`` for
    channel N of a block. A device of format 1's layout comes first (by
    type), its blocks channel by channel (as its rows are); then the map
    devices, in the order of each map's points."""
    q = "SELECT type, humidity_units, channels, id FROM devices" + (
        " WHERE name = ?" if device else "")
    rows = [(has_map(db, kind), kind, layout, channels, did) for kind, layout, channels, did
            in db.execute(q, (device,) if device else ()).fetchall()]
    rows.sort(key=lambda r: (r[0], "" if r[0] else r[1], r[4]))
    cols: dict[str, Point] = {}
    for _, kind, layout, channels, _ in rows:
        got = device_map(db, kind, layout, channels, given)
        if got is None:
            continue
        m, group = got
        points = [m.points[n] for n in group_points(m, group)]
        if channels:  # by channel
            for c in range(1, channels + 1):
                for p in points:
                    cols.setdefault(f"{p.name}_{c}", p)
            continue
        for p in points:
            for c in range(1, p.channels + 1) if p.block else (0,):
                cols.setdefault(f"{p.name}_{c}" if c else p.name, p)
    return cols


def map_point_names(path: str, given: Mapping[str, Map] | None = None) -> list[str]:
    """The point names of the devices a database at ``path`` holds (by
    their maps: the stored ones, or those in ``given``), in the maps' order."""
    db = open_readonly(path)
    try:
        return list(dict.fromkeys(p.name for p in map_columns(db, None, given).values()))
    finally:
        db.close()


class _Device:
    """What decodes one device row's samples: the row as the logger's
    :class:`DeviceInfo`, its map (the stored copy, or the shipped map of its
    type for a device of format 1's layout, configured by the row: its
    channels and humidity units) and group, where the group's points sit in
    the stored registers, and (a row of channels) each channel's unit."""

    def __init__(self, row: DeviceRow, given: Mapping[str, Map] | None) -> None:
        units = [0.1 if t else 1.0 for t in row.tenths]
        unit: float | tuple[float, ...] = (
            units[0] if len(set(units)) == 1 else tuple(units)) if units else 0.1
        kind, channels = row.kind, row.channels
        self.info = DeviceInfo(row.bus, row.port, kind, row.address, row.name, channels, unit)
        self.channels = int(channels)
        self.unit, self.other = humidity_units(unit, self.channels) if units else (0.1, b"")
        if row.map_source is not None:
            found = _configured(row.map_source, kind, row.layout, given)
            how: GroupDecode | None = GroupDecode(*found)
        else:  # the shipped map's, made once
            how = _shipped_decode(kind, self.channels, self.unit if units else None)
        if how is None:
            raise InvalidArgument(f"the database has no map {kind!r} for device {row.name}")
        self.how = how
        self.map, self.group, self.names = how.map, how.group, how.names
        self.decoders = how.decoders
        self.buffers = [d.new_buffers() for d in self.decoders]  # this reader's own

    def reading(self, blob: bytes | None, unsupported: int, hub: Sequence[HubRow] = ()
                ) -> MapReading:
        """A stored sample decoded again: its registers (a sample stored by
        channel, ``registers`` NULL: its rows of ``hub_changes``, ``hub``, the
        channels not there ``not_read``), the points refused ``unsupported``."""
        present: list[int] | None = None
        if blob is not None:
            regs = host_words(blob)
        else:
            regs, present = self._by_channel(hub)
        gone = [n for i, n in enumerate(self.names)
                if unsupported >> min(i, MAP_UNSUPPORTED_BITS) & 1]
        if self.channels:
            return self._blocks(regs, gone, present)
        values, states = self.how.decode(regs, self.how.unread_of(gone) if gone else _NONE)
        return MapReading(self.map, self.group, values, states, regs, tuple(gone))

    def _by_channel(self, hub: Sequence[HubRow]) -> tuple[array[int], list[int]]:
        """The registers of a sample stored by channel (a word per point and
        channel, from its rows of ``hub_changes``), and its channels (0-based)."""
        first = self.decoders[0].address
        slots = [(p.address - first, p.stride) for p in map(self.map.points.get, self.names)
                 if p is not None]
        regs = array("H", bytes(2 * sum(d.count for d in self.decoders)))
        present = []
        for ch, blob in hub:
            if not 1 <= ch <= self.channels:
                continue
            for (at, stride), word in zip(slots, host_words(blob), strict=False):
                regs[at + (ch - 1) * stride] = word
            present.append(ch - 1)
        return regs, present

    def _blocks(self, regs: array[int], gone: list[str], present: list[int] | None
                ) -> MapReading:
        """A reading of blocks of one channel count each, kept as arrays
        (:class:`Blocks`), as a device read by channel gives it."""
        values, states = array("d"), array("B")
        index: dict[str, int] = {}
        at = 0
        for dec, into in zip(self.decoders, self.buffers, strict=True):
            b = dec.decode(regs[at:at + dec.count], into)
            index.update((n, len(values) + dec.slot(n)) for n in dec.names)
            values.extend(b.values[:dec.slots])
            states.extend(b.states[:dec.slots])
            at += dec.count
        c = self.channels
        blocks = Blocks(self.names, c, values, states, {n: index[n] for n in self.names})
        blocks_in_other_units(blocks, regs, self.unit, self.other)
        for n in gone:
            i = index[n]
            values[i:i + c] = array("d", [math.nan] * c)
            states[i:i + c] = array("B", [_UNSUPPORTED] * c)
        if present is not None:
            keep = set(present)
            for i in index.values():
                for ch in range(c):
                    if ch not in keep:
                        values[i + ch], states[i + ch] = math.nan, _NOT_READ
        return MapReading(self.map, self.group, blocks.value_map(), blocks.state_map(), regs,
                          tuple(gone))


_UNSUPPORTED, _NOT_READ = STATES.index("unsupported"), STATES.index("not_read")
_NONE: frozenset[int] = frozenset()


def has_map(db: sqlite3.Connection, kind: str) -> bool:
    """Whether the database stored a map of id ``kind`` (a map device's)."""
    return bool(db.execute("SELECT 1 FROM sqlite_master WHERE name = 'maps'").fetchone()) and \
        bool(db.execute("SELECT 1 FROM maps WHERE id = ?", (kind,)).fetchone())


def shipped_map(kind: str, channels: int = 0, unit: float | tuple[float, ...] | None = None
                ) -> tuple[Map, str | None] | None:
    """The map of a device of format 1's layout (a devices row with no map
    of its own: the shipped map of its type), configured as the row says
    (its ``channels``, its channels' humidity ``unit``, the most common for
    a unit per channel), and the group its samples hold (the map's first);
    None for a type with no shipped map."""
    return _shipped(kind, channels, None if unit is None else humidity_units(unit, channels)[0])


@functools.lru_cache(maxsize=64)
def _shipped(kind: str, channels: int, unit: float | None) -> tuple[Map, str | None] | None:
    try:
        m = maps.builtin(kind)
    except MapError:
        return None
    options: dict[str, float] = {}
    if channels:
        options["channels"] = channels
    if unit is not None:
        options["humidity_unit"] = unit
    m = m.configure(options) if options else m
    return m, next(iter(m.groups), None)


@functools.lru_cache(maxsize=64)
def _shipped_decode(kind: str, channels: int, unit: float | None) -> GroupDecode | None:
    got = _shipped(kind, channels, unit)
    return None if got is None else GroupDecode(*got)


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
    InvalidArgument. A hub's sample is a :class:`~pymb.devices.HubReading`,
    a CoolPro's a :class:`~pymb.devices.CoolProTelemetry`, any other
    device's a :class:`~pymb.devices.mapreading.MapReading`
    (:func:`pymb.devices.readings.reading_view`)."""
    return [dataclasses.replace(s, data=reading_view(map_reading(s.data)))
            for s in stored_after(db, sample_id, limit, before)]


def stored_after(db: sqlite3.Connection | str | os.PathLike[str], sample_id: int,
                 limit: int = 1000, before: int | None = None) -> list[StoredSample]:
    """:func:`samples_after` with every sample a
    :class:`~pymb.devices.mapreading.MapReading` of its map."""
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


def iter_samples(con: sqlite3.Connection, where: str, args: Sequence[SqlArg],
                  limit: int | None = None, given: Mapping[str, Map] | None = None
                  ) -> Iterator[StoredSample]:
    """The samples ``where`` says, decoded (map devices by their stored map,
    or by the one in ``given``)."""
    devices: dict[int, _Device] = {}
    q = ("SELECT s.id, s.device_id, s.time_utc, s.monotonic, s.registers, s.unsupported "
         f"FROM samples s WHERE {where} ORDER BY s.id" + ("" if limit is None else " LIMIT ?"))
    for sid, did, t, mono, blob, unsupported in con.execute(
            q, (*args, limit) if limit is not None else tuple(args)).fetchall():
        dev = devices.get(did)
        if dev is None:
            dev = devices[did] = _Device(device_row(con, did), given)
        hub = () if blob is not None else con.execute(
            "SELECT channel, registers FROM hub_changes WHERE device_id = ? AND time_utc = ? "
            "AND sample_id = ?", (did, t, sid)).fetchall()
        yield StoredSample(dev.info, t, mono, dev.reading(blob, unsupported, hub), sid)


@dataclasses.dataclass(frozen=True)
class DeviceRow:
    """A ``devices`` row as plain data: its columns, its channels' humidity
    tenths, and the text of its stored map (None: a device of format 1's
    layout, decoded by its shipped map)."""

    bus: str
    port: str
    kind: str
    address: int
    name: str
    channels: int
    layout: str
    tenths: tuple[int, ...]
    map_source: str | None


def device_row(db: sqlite3.Connection, did: int) -> DeviceRow:
    """The ``devices`` row ``did`` of ``db`` as data (see :class:`DeviceRow`)."""
    bus, port, kind, address, name, channels, layout = db.execute(
        "SELECT bus, port, type, address, name, channels, humidity_units FROM devices "
        "WHERE id = ?", (did,)).fetchone()
    tenths = tuple(int(t) for (t,) in db.execute(
        "SELECT humidity_tenths FROM channels WHERE device_id = ? ORDER BY channel", (did,)))
    source = db.execute("SELECT source FROM maps WHERE id = ?", (kind,)).fetchone() \
        if has_map(db, kind) else None
    return DeviceRow(bus, port, kind, address, name, channels, layout, tenths,
                     None if source is None else str(source[0]))


class RowDecoder:
    """Sample rows given as data (a writer's, handed to a forwarder: see
    :mod:`pymb.store.handoff`) decoded as :func:`iter_samples` decodes the
    rows it reads; one per thread (each device's decode buffers are its own)."""

    def __init__(self) -> None:
        self._devices: dict[int, tuple[DeviceRow, _Device]] = {}

    def knows(self, did: int, row: DeviceRow) -> bool:
        """Whether device row ``did`` was added as ``row`` (this object: a
        writer's rolled-back batch may give its id to another device, whose
        row comes as a new object)."""
        got = self._devices.get(did)
        return got is not None and got[0] is row

    def add(self, did: int, row: DeviceRow) -> None:
        """The devices row ``did`` (see :func:`device_row`), in place of any before."""
        self._devices[did] = (row, _Device(row, None))

    def sample(self, row: SampleRow, hub: Sequence[HubRow]) -> StoredSample:
        """A ``samples`` row (and, stored by channel, its ``hub_changes``
        rows) decoded; its device was added."""
        sid, did, t, mono, blob, unsupported = row
        dev = self._devices[did][1]
        return StoredSample(dev.info, t, mono, dev.reading(blob, unsupported, hub), sid)
