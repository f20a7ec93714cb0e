"""One read of a map device's polling group as the logger keeps it:
:class:`MapReading`, the registers the group's requests read (stored once,
as the hub's sweep is) with the values and states the C decoder made of
them, and :func:`group_layout`, where each table's registers sit in them."""

from __future__ import annotations

from array import array
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from pymb.maps import Decoder, Map, Value

__all__ = ["MapReading", "group_layout", "group_points"]


def group_points(m: Map, group: str | None) -> list[str]:
    """The readable points a poll of ``group`` reads, in map order (every
    readable point for None), then the scale factors of its ``scale_from``
    points that are not in it."""
    return list(m.with_scale_factors(p.name for p in m.points.values()
                                     if p.access != "w" and (group is None or p.group == group)))


def group_layout(m: Map, group: str | None) -> list[Decoder]:
    """The decoders of a group's registers, one per table in the order of
    the group's first point in each: their registers, ``count`` words from
    ``address`` each, one after the other, are what a sample stores."""
    tables: dict[str, list[str]] = {}
    for name in group_points(m, group):
        tables.setdefault(m.points[name].table, []).append(name)
    return [Decoder(m, names) for names in tables.values()]


@dataclass(frozen=True)
class MapReading:
    """A map device's group, read once: ``values`` and ``states`` by point
    name (blocks as lists), and ``registers``, the group's tables one after
    the other as :func:`group_layout` lays them (bits as 0/1 words).
    ``unsupported``: the points the device refused, in map order.
    ``wire``: the same registers as big-endian bytes (as on the wire and as
    the store keeps them) when the reader already had them so, or None."""

    map: Map
    group: str | None
    values: Mapping[str, Value]
    states: Mapping[str, Any]
    registers: array[int]
    unsupported: tuple[str, ...] = ()
    wire: bytes | None = field(default=None, compare=False, repr=False)

    @property
    def channels(self) -> int:
        """0: a map reading has no hub channels."""
        return 0
