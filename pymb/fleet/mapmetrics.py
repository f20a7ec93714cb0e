"""A map device's points as the fleet publishes them: the Sparkplug B
datatype of each point's type, its metric names (a block's channels one
metric each), its birth properties (unit, counter), and the plain profile's
retained metadata message."""

from __future__ import annotations

import json
from collections.abc import Iterator

from pymb.devices.mapreading import MapReading
from pymb.fleet.protobuf import DataType, MetricValue, Properties
from pymb.jsonvalue import JsonObject
from pymb.maps import Map, Point, Value

__all__ = ["datatype", "map_metadata", "map_metrics", "plain_value", "point_properties"]

_TYPES = {
    "u16": DataType.UINT16, "i16": DataType.INT16, "u32": DataType.UINT32,
    "i32": DataType.INT32, "u64": DataType.UINT64, "i64": DataType.INT64,
    "u8_hi": DataType.UINT8, "u8_lo": DataType.UINT8, "i8_hi": DataType.INT8,
    "i8_lo": DataType.INT8, "f16": DataType.FLOAT, "f32": DataType.FLOAT,
    "f64": DataType.DOUBLE, "string": DataType.STRING, "bool": DataType.BOOLEAN,
    "bit": DataType.BOOLEAN, "bits": DataType.UINT16, "sm16": DataType.INT16,
    "sunssf": DataType.INT16, "raw": DataType.STRING,
}


def datatype(p: Point) -> DataType:
    """The Sparkplug B datatype of a point: its type's, Double when scaled."""
    if p.scale is not None or p.offset is not None or p.scale_from is not None:
        return DataType.DOUBLE
    return _TYPES[p.type]


def _names(p: Point) -> Iterator[tuple[str, int | None]]:
    if p.block:
        for c in range(1, p.channels + 1):
            yield f"channel {c:03d}/{p.name}", c - 1
    else:
        yield p.name, None


def plain_value(v: Value) -> MetricValue:
    """A value as a metric carries it: raw registers as hex text, NaN as null."""
    if isinstance(v, list):  # raw registers
        return "".join(f"{r:04X}" for r in v)
    if isinstance(v, float) and v != v:
        return None
    return v


def map_metrics(data: MapReading, every: bool
                ) -> list[tuple[str, DataType, MetricValue, str, Point]]:
    """(name, datatype, value, state, point) of a reading's metrics; with
    ``every``, each readable point of the map (a birth: those of other groups
    null, state ``not_read``)."""
    out = []
    m = data.map
    for p in m.points.values():
        if p.access == "w" or (not every and p.name not in data.values):
            continue
        v = data.values.get(p.name)
        st = data.states.get(p.name, "not_read")
        dt = datatype(p)
        for name, ch in _names(p):
            if ch is None or p.type == "raw":
                value, state = plain_value(v), st
            else:
                value = plain_value(v[ch]) if isinstance(v, list) else None
                state = st[ch] if isinstance(st, list) else st
            out.append((name, dt, value, str(state), p))
    return out


def point_properties(p: Point) -> Properties:
    """A point's properties in its birth: ``engUnit`` and, for a counter, ``kind``."""
    props: list[tuple[str, DataType, int | str]] = []
    if p.unit:
        props.append(("engUnit", DataType.STRING, p.unit))
    if p.kind != "gauge":
        props.append(("kind", DataType.STRING, p.kind))
    return tuple(props)


def map_metadata(m: Map) -> bytes:
    """The plain profile's retained ``{prefix}/{node}/{device}/meta``: the map's
    id and each readable point's unit, kind, type, group and channels."""
    points = {}
    for p in m.points.values():
        if p.access == "w":
            continue
        doc: JsonObject = {"unit": p.unit, "kind": p.kind, "type": p.type,
                               "group": p.group}
        if p.block:
            doc["channels"] = p.channels
        points[p.name] = doc
    return json.dumps({"map": m.id, "points": points}, separators=(",", ":")).encode()
