"""One quantity of one device over time (``pymb plot``), and the lookups the
data commands share: a device by name or ``TYPE[:ADDRESS]``, a quantity by
name, a time span."""

from __future__ import annotations

import os
import sqlite3
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass

from pymb.devices.mapreading import group_points
from pymb.devices.spec import closest, parse_address, split_spec
from pymb.errors import InvalidArgument
from pymb.maps import Map
from pymb.store.reader import device_map, iter_samples, shipped_map
from pymb.store.readonly import reading
from pymb.store.records import StoredSample, reading_value
from pymb.store.schema import SCHEMA_VERSION, SqlArg, schema_version
from pymb.store.summary import devices

__all__ = ["Series", "quantities", "resolve_device", "sample_filter", "series"]


def quantities(kind: str) -> list[str]:
    """The quantities a device of format 1's layout (``hub``, ``coolpro``:
    a shipped map) stores: the points of its map's group; none for another."""
    got = shipped_map(kind)
    return [] if got is None else group_points(*got)


def resolve_device(con: sqlite3.Connection, wanted: str, path: str) -> tuple[str, str]:
    """(name, type) of the device ``wanted`` (its name, or ``TYPE[:ADDRESS]``)
    in an open database; an error listing the devices there if it is not one."""
    devs = devices(con)
    for name, kind, _, _ in devs:
        if name == wanted:
            return name, kind
    matches: list[tuple[str, str]] = []
    kind, addr, _ = split_spec(wanted)  # any type: a map device's too
    try:
        address = None if addr is None else parse_address(addr, wanted)
    except InvalidArgument:
        kind = ""
    if kind:
        matches = [(n, t) for n, t, a, _ in devs
                   if t == kind and (address is None or a == address)]
    if len(matches) == 1:
        return matches[0]
    if len(matches) > 1:
        raise InvalidArgument(f"device {wanted!r} matches several devices in {path}: "
                              f"{', '.join(n for n, _ in matches)}; give one of those names")
    listing = ", ".join(f"{n} ({t}:{a} on {b})" for n, t, a, b in devs) or "none"
    raise InvalidArgument(f"no device {wanted!r} in {path}; it has: {listing}")


def sample_filter(device: str | None, since: float | None, until: float | None,
                  table: str = "s") -> tuple[str, list[SqlArg]]:
    """The WHERE clause (over ``samples s``, or the rows of another ``table``
    alias with a ``device_id`` and a ``time_utc``: ``events e``) and its
    arguments for a device name and a time span (``since`` included,
    ``until`` excluded)."""
    parts: list[str] = ["1"]
    args: list[SqlArg] = []
    if device is not None:
        parts.append(f"{table}.device_id IN (SELECT id FROM devices WHERE name = ?)")
        args.append(device)
    if since is not None:
        parts.append(f"{table}.time_utc >= ?")
        args.append(since)
    if until is not None:
        parts.append(f"{table}.time_utc < ?")
        args.append(until)
    return " AND ".join(parts), args


def chunks(con: sqlite3.Connection, where: str, args: Sequence[SqlArg],
           size: int = 500, given: Mapping[str, Map] | None = None) -> Iterator[StoredSample]:
    """The samples ``where`` says, in id order, decoded a chunk at a time (a
    long file never sits in memory)."""
    last = 0
    while True:
        chunk = list(iter_samples(con, f"{where} AND s.id > ?", (*args, last), size, given))
        yield from chunk
        if len(chunk) < size:
            return
        last = chunk[-1].id


@dataclass(frozen=True)
class Series:
    """A quantity over time: UTC seconds and values (NaN where the device
    gave none: offline, no sensor, unsupported)."""

    device: str
    type: str
    quantity: str
    channel: int | None
    unit: str
    times: list[float]
    values: list[float]


def series(path: str | os.PathLike[str], device: str, quantity: str, *,
           channel: int | None = None, since: float | None = None,
           until: float | None = None) -> Series:
    """``quantity`` of ``device`` (a name or ``TYPE[:ADDRESS]``; a hub's
    ``channel``) from the database at ``path``, between ``since`` and
    ``until``. Samples of an ``--on-change`` log that did not store the
    channel have no point."""
    with reading(path) as con:
        if schema_version(con) != SCHEMA_VERSION:
            raise InvalidArgument(f"{path} is not a pymb database of format {SCHEMA_VERSION}")
        name, kind = resolve_device(con, device, str(path))
        channels = int(con.execute("SELECT channels FROM devices WHERE name = ?",
                                   (name,)).fetchone()[0])
        stored = device_map(con, kind, "", channels)
        if stored is None:
            raise InvalidArgument(f"{path}: the database has no map {kind!r} for {name}")
        m = stored[0]
        # a device stored by channel: its blocks (one a channel); else its points
        known = [n for n in group_points(*stored) if m.points[n].block == bool(channels)]
        if quantity not in known:
            raise InvalidArgument(f"{name} ({kind}) has no quantity {quantity!r}"
                                  f"{closest(quantity, known)}")
        if m.points[quantity].type in ("string", "raw"):
            raise InvalidArgument(f"{name}'s {quantity} is text, not a number: there is "
                                  f"nothing to draw (pymb export --quantity {quantity} "
                                  "lists its values)")
        if channels:  # a hub's
            if channel is None:
                raise InvalidArgument(f"{name} is a {kind}: give --channel (1..{channels})")
            if not 1 <= channel <= channels:
                raise InvalidArgument(f"--channel {channel}: {name} has channels 1..{channels}")
        elif channel is not None:
            raise InvalidArgument(f"--channel is for a hub; {name} is a {kind}")
        where, args = sample_filter(name, since, until)
        times: list[float] = []
        values: list[float] = []
        for s in chunks(con, where, args):
            v = reading_value(s.data, quantity, channel)
            if v is None:
                continue  # another group's sample, a channel an --on-change sample did not store
            times.append(s.time_utc)
            values.append(v)
        return Series(name, kind, quantity, channel, m.points[quantity].unit, times, values)
