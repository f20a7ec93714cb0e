"""What the SQLite writer puts in its rows: the multi-row INSERT of
samples (of :class:`~pymb.store.Sample` records, or of a block of polls'
columns), the ``unsupported`` column, the ``devices`` rows (a hub's humidity
units) and a map device's ``maps`` row and views."""

from __future__ import annotations

import functools
import operator
import sqlite3
from array import array
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from pymb import maps
from pymb.devices.mapreading import MapReading, group_layout
from pymb.devices.readings import Reading, map_reading
from pymb.errors import InvalidArgument, OutputError
from pymb.store.block import PollBlock, PollSource
from pymb.store.mapcheck import changed_map_message
from pymb.store.mapviews import create_map_views
from pymb.store.reader import HubRow
from pymb.store.records import DeviceInfo, Event, Sample
from pymb.store.schema import FORMAT1_LAYOUT, map_layout_key, unsupported_mask, wire_bytes

__all__ = ["ROWS_PER_INSERT", "BoundRows", "DeviceIds", "block_binds", "block_rows",
           "bound_registers", "channel_rows", "humidity_units", "insert_block_rows", "insert_rows",
           "sample_rows", "stored_registers", "unsupported_of"]

#: Rows one multi-row INSERT of samples carries at most (6 values each, far
#: below SQLite's limit of bound variables).
ROWS_PER_INSERT = 64
_SEEN_MAX = 4096  #: device configurations :meth:`DeviceIds.id_of` knows by identity


@functools.lru_cache(maxsize=ROWS_PER_INSERT)
def insert_rows(n: int) -> str:
    """The INSERT of ``n`` sample rows (id, device_id, time_utc, monotonic,
    registers, unsupported)."""
    return ("INSERT INTO samples(id, device_id, time_utc, monotonic, registers, unsupported) "
            "VALUES " + ", ".join(["(?, ?, ?, ?, ?, ?)"] * n))


@functools.lru_cache(maxsize=ROWS_PER_INSERT)
def insert_block_rows(n: int) -> str:
    """The INSERT of ``n`` sample rows of a block's polls, none of which
    refused a point: ``?1`` the first row's id, ``?2`` the block's clock
    (:attr:`PollBlock.clock <pymb.store.block.PollBlock.clock>`), then 3
    values a row (device id, monotonic time, registers). SQLite makes the
    rest of each row: its id (``?1`` plus the row's place), its wall time
    (the clock plus its monotonic time: the same IEEE addition of the same
    two doubles as :func:`block_rows` makes) and an ``unsupported`` of 0."""
    return ("INSERT INTO samples(id, device_id, time_utc, monotonic, registers, unsupported) "
            "VALUES " + ", ".join(f"(?1 + {k}, ?{3 * k + 3}, ?2 + ?{3 * k + 4}, ?{3 * k + 4}, "
                                  f"?{3 * k + 5}, 0)" for k in range(n)))


@dataclass
class BoundRows:
    """Rows of ``samples`` as the writer binds them, in multi-row INSERTs:
    ``flat`` their values, 6 a row (:func:`insert_rows`), or with a
    ``clock`` 3 a row after the first id and the clock
    (:func:`insert_block_rows`); ``sizes`` each row's bytes of registers."""

    flat: list[object]
    sizes: list[int]
    clock: float | None = None
    first: int = 0  #: (with a clock) the first row's id

    def statement(self, i: int, k: int) -> tuple[str, list[object]]:
        """The INSERT of rows ``i`` to ``i + k`` and its values."""
        if self.clock is None:
            return insert_rows(k), self.flat[6 * i:6 * (i + k)]
        return insert_block_rows(k), [self.first + i, self.clock, *self.flat[3 * i:3 * (i + k)]]

    def starting(self, first: int) -> BoundRows:
        """These rows, their ids from ``first`` on."""
        self.first = first
        return self


def stored_registers(data: MapReading, size: int = 0) -> bytes:
    """The ``registers`` column of a reading: big-endian words (the
    reading's own bytes when its reader had them so, as the TCP loop does),
    at least ``size`` bytes (format 1's layout: the registers of its shipped
    map's group, a hub's 31..730, whatever its channels)."""
    wire = data.wire
    if wire is not None and len(wire) >= size:
        return wire
    out = wire_bytes(data.registers)
    if len(out) < size:
        out += bytes(size - len(out))
    return out


def bound_registers(data: MapReading, size: int = 0) -> bytearray:
    """:func:`stored_registers` as the writer binds it: a bytearray, which
    :mod:`sqlite3` binds as a BLOB straight away (the same BLOB); a bytes
    object it first offers to its adapters, each refusal an AttributeError
    with its message made (about 3,300 instructions a row, callgrind)."""
    return bytearray(stored_registers(data, size))


def sample_rows(samples: Sequence[Sample], first: int, ids: DeviceIds) -> BoundRows:
    """The ``samples`` table's rows of ``samples`` (ids from ``first`` on,
    devices' ids from ``ids``) as :func:`insert_rows` binds them, 6 values a
    row one after the other, and each row's bytes of registers."""
    flat: list[object] = []
    sizes: list[int] = []
    device_id = ids.id_of
    sid = first
    for s in samples:
        data = s.data
        if not isinstance(data, MapReading):
            data = map_reading(data)
        did, _, size = device_id(s.device, data)
        wire = data.wire  # (bound_registers, without its two calls a row)
        blob = bytearray(wire) if wire is not None and len(wire) >= size else \
            bound_registers(data, size)
        sizes.append(len(blob))
        flat.extend((sid, did, s.time_utc, s.monotonic, blob,
                     unsupported_of(data) if data.unsupported else 0))
        sid += 1
    return BoundRows(flat, sizes)


def block_rows(block: PollBlock, first: int, ids: DeviceIds) -> BoundRows:
    """:func:`sample_rows` of a block of polls, bound straight from its
    columns: the same rows its :meth:`~pymb.store.block.PollBlock.samples`
    would give."""
    flat: list[object] = []
    data = memoryview(block.data)
    offs = block.offs
    ends = [*offs[1:], len(data)]
    clock = block.clock
    unread = block.unread
    known = ids.by_source.get
    sid = first
    for j, (src, mono) in enumerate(zip(block.sources, block.monos, strict=True)):
        did, size = known(src) or ids.id_of_source(src, block, j)
        blob = bytearray(data[offs[j]:ends[j]])
        if size:  # (format 1's layout: at least its map's registers)
            blob += bytes(max(0, size - len(blob)))
            ends[j] = offs[j] + len(blob)
        gone = unread[j] if unread else None
        how = src.decode
        flat.extend((sid, did, clock + mono, mono, blob, unsupported_mask(
            how.map, how.group, how.unsupported(gone)) if gone else 0))
        sid += 1
    return BoundRows(flat, list(map(operator.sub, ends, offs)))


def block_binds(block: PollBlock, ids: DeviceIds) -> BoundRows | None:
    """The rows of :func:`block_rows`, 3 values a row as
    :func:`insert_block_rows` binds them (no id, wall time or ``unsupported``
    object a row: SQLite makes them), when that is how they go: no poll
    refused a point, each device's ids known (:attr:`DeviceIds.by_source`,
    its first block's :func:`block_rows` finds them), no registers to pad
    (format 1's layout: a poll shorter than its map's group). None
    otherwise. A column at a time (a row's registers: a slice of the
    block's bytearray), not a tuple a row."""
    if block.unread is not None or not block.sources:
        return None
    try:
        got = list(map(ids.by_source.__getitem__, block.sources))
    except KeyError:
        return None
    dids, sizes = zip(*got, strict=True)
    data = block.data
    offs = block.offs
    ends = [*offs[1:], len(data)]
    lengths = list(map(operator.sub, ends, offs))
    if any(sizes) and any(map(operator.lt, lengths, sizes)):
        return None
    if not isinstance(data, bytearray):  # (a slice of one is a bytearray: one object a row)
        data = bytearray(data)
    flat: list[object] = [None] * (3 * len(got))  # (each column set in one step)
    flat[0::3] = dids
    flat[1::3] = block.monos
    flat[2::3] = [data[a:b] for a, b in zip(offs, ends, strict=True)]
    return BoundRows(flat, lengths, block.clock)


def channel_rows(data: MapReading, pick: Iterable[int]) -> list[HubRow]:
    """The ``hub_changes`` rows' (channel, registers) of a reading stored by
    channel: the channels ``pick`` (0-based), each its points' registers."""
    regs = data.registers
    points = [data.map.points[n] for n in data.values]
    first = min(p.address for p in points)
    return [(ch + 1, wire_bytes(array(
        "H", [regs[p.address - first + ch * p.stride] for p in points]))) for ch in pick]


@functools.lru_cache(maxsize=64)
def _shipped(kind: str) -> tuple[int, int]:
    """(channels, bytes) of format 1's layout of device type ``kind``: its
    shipped map's blocks' channels (0: none) and registers of its group."""
    m = maps.builtin(kind)
    group = next(iter(m.groups), None)
    return (max((p.channels for p in m.points.values() if p.block), default=0),
            2 * sum(d.count for d in group_layout(m, group)))


def unsupported_of(data: MapReading) -> int:
    """The ``unsupported`` column: the points refused (bit i: the group's
    i-th point; a hub's blocks)."""
    if data.unsupported:
        return unsupported_mask(data.map, data.group, data.unsupported)
    return 0


def humidity_units(d: DeviceInfo, channels: int) -> tuple[str, bytes]:
    """A hub's humidity units: the ``devices.humidity_units`` text and a
    ``channels`` byte per channel (1: 0.1 %, 0: 1 %)."""
    u = d.humidity_unit
    units = [u] * channels if isinstance(u, (int, float)) else list(u)
    if len(units) != channels:
        raise InvalidArgument(f"{d.name}: {len(units)} humidity units for {channels} channels")
    tenths = bytes(0 if x == 1 else 1 for x in units)
    text = f"{units[0]:g}" if len(set(units)) == 1 else ",".join(f"{x:g}" for x in units)
    return text, tenths


class DeviceIds:
    """The ``devices`` (and ``channels``, ``maps``) rows of one SQLite writer
    (:class:`pymb.store.writer.SqliteSink` owns one): a device
    configuration's ids, inserted on first use. ``begin`` opens the writer's
    transaction when none is open; :meth:`forget` drops what a rolled-back
    batch inserted."""

    def __init__(self, db: sqlite3.Connection, path: Path,
                 begin: Callable[[], None]) -> None:
        self.db = db
        self.path = path
        self._begin = begin
        self._devices: dict[DeviceInfo | tuple[DeviceInfo, str | None], tuple[int, int, int]] = {}
        #: (id of a configuration, group) -> (that configuration, its ids): the
        #: logger hands the same object with every sample of a device, so this
        #: finds it without hashing its fields
        self._seen: dict[tuple[int, str | None], tuple[DeviceInfo, tuple[int, int, int]]] = {}
        self._viewed: set[str] = set()  #: map ids whose views this session made
        #: (device id, bytes) of the polls of a :class:`~pymb.store.block.PollSource`,
        #: as :meth:`id_of_source` found them (the TCP loop names a polling
        #: group's polls with one source, so this finds it by identity)
        self.by_source: dict[PollSource, tuple[int, int]] = {}

    def forget(self) -> None:
        """The batch was rolled back: the ids it inserted and the views it
        made are gone."""
        self._devices.clear()
        self._seen.clear()
        self._viewed.clear()
        self.by_source.clear()

    def id_of(self, d: DeviceInfo, data: Reading | Event) -> tuple[int, int, int]:
        """(device id, channels, bytes) of a device configuration, inserted on
        first use: a map device has a row per group and its map stored; a
        device of format 1's layout (:data:`FORMAT1_LAYOUT`) has its map's
        ``channels`` (stored by channel when not 0) and their humidity units
        in its row, its registers at least ``bytes``."""
        own = d.type in FORMAT1_LAYOUT
        mapped = data if not own and isinstance(data, MapReading) else None
        mine = (id(d), mapped.group if mapped is not None else None)
        seen = self._seen.get(mine)
        if seen is not None and seen[0] is d:
            return seen[1]
        cache = (d, mapped.group) if mapped is not None else d
        got = self._devices.get(cache)
        if got is not None:
            self._remember(mine, d, got)
            return got
        channels, units, tenths, size = 0, "", b"", 0
        if mapped is not None:
            if not d.map_source:
                raise InvalidArgument(f"{d.name}: a device of type {d.type!r} is stored with "
                                      "its map's text (DeviceInfo.map_source), and it has none")
            units = map_layout_key(mapped.group, d.map_options)
        elif own:  # its channels, or as read (DeviceInfo.channels 0)
            most, size = _shipped(d.type)
            channels = d.channels or (max((p.channels for p in data.map.points.values()
                                           if p.block), default=0)
                                      if isinstance(data, MapReading) else most)
            units, tenths = humidity_units(d, channels)
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
        if mapped is not None:
            self._store_map(d, mapped)
        got = (int(did), channels, size)  # type: ignore[arg-type]
        if not isinstance(data, Event):
            self._devices[cache] = got
            self._remember(mine, d, got)
        return got

    def id_of_source(self, src: PollSource, block: PollBlock, j: int) -> tuple[int, int]:
        """(device id, bytes) of the device of ``src``, whose poll ``j`` of
        ``block`` is being stored: :meth:`id_of` with that poll's reading,
        made only the first time."""
        d = src.device
        seen = self._seen.get((id(d), src.decode.group))
        got = seen[1] if seen is not None and seen[0] is d else self.id_of(d, block.sample(j).data)
        if len(self.by_source) >= _SEEN_MAX:  # a caller with a new source per poll
            self.by_source.clear()
        out = self.by_source[src] = (got[0], got[2])
        return out

    def _remember(self, mine: tuple[int, str | None], d: DeviceInfo,
                  got: tuple[int, int, int]) -> None:
        if len(self._seen) >= _SEEN_MAX:  # a caller with a new object per sample
            self._seen.clear()
        self._seen[mine] = (d, got)

    def _store_map(self, d: DeviceInfo, data: MapReading) -> None:
        """A map device's map beside its samples, and its views, made once a session (a
        file's older views too). A map id keeps its first text (:mod:`pymb.store.mapcheck`)."""
        row = self.db.execute("SELECT source FROM maps WHERE id = ?", (d.type,)).fetchone()
        if row is None:
            self.db.execute("INSERT INTO maps(id, source) VALUES (?, ?)",
                            (d.type, d.map_source))
        elif row[0] != d.map_source:
            raise OutputError(changed_map_message(self.path, d.type))
        if d.type not in self._viewed:
            create_map_views(self.db, data.map)
            self._viewed.add(d.type)
