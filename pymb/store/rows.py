"""What the SQLite writer puts in a row: the multi-row INSERT of samples,
the ``unsupported`` column, a hub's humidity units."""

from __future__ import annotations

import functools
from typing import Any

from pymb.devices import HubReading
from pymb.devices.mapreading import MapReading
from pymb.errors import InvalidArgument
from pymb.store.records import DeviceInfo
from pymb.store.schema import unsupported_mask

__all__ = ["ROWS_PER_INSERT", "humidity_units", "insert_rows", "unsupported_of"]

#: Rows one multi-row INSERT of samples carries at most (5 values each, far
#: below SQLite's limit of bound variables).
ROWS_PER_INSERT = 64


@functools.lru_cache(maxsize=ROWS_PER_INSERT)
def insert_rows(n: int) -> str:
    """The INSERT of ``n`` sample rows (device_id, time_utc, monotonic,
    registers, unsupported)."""
    return ("INSERT INTO samples(device_id, time_utc, monotonic, registers, unsupported) "
            "VALUES " + ", ".join(["(?, ?, ?, ?, ?)"] * n))


def unsupported_of(data: Any) -> int:
    """The ``unsupported`` column: a hub's blocks, a map reading's points."""
    if isinstance(data, HubReading):
        return data.unsupported_mask
    if isinstance(data, MapReading) and data.unsupported:
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
