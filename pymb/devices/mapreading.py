"""One read of a map device's polling group as the logger keeps it:
:class:`MapReading`, the registers the group's requests read (stored once,
as the hub's sweep is) with the values and states the C decoder made of
them, :func:`group_layout`, where each table's registers sit in them, and
:class:`GroupDecode`, what decodes them."""

from __future__ import annotations

import threading
from array import array
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from pymb.maps import Decoder, Map, Value
from pymb.maps.device_plan import MapItems
from pymb.maps.types import STATES

__all__ = ["Blocks", "GroupDecode", "MapReading", "group_layout", "group_points"]


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


class GroupDecode:
    """A group's registers (laid out as :func:`group_layout` says) decoded as
    MapDevice decodes them: a C decoder per table, NaN/None and
    ``unsupported`` where the device refused a point. The one decoder of a
    stored or polled group: the TCP logger's samples and the store's reader
    decode with it. ``items``: the map's planner items (made when not given)."""

    def __init__(self, m: Map, group: str | None, items: MapItems | None = None) -> None:
        if items is None:
            items = MapItems.of(m)
        self.map = m
        self.group = group
        self.decoders = group_layout(m, group)
        self.names = group_points(m, group)
        index = {p.name: i for i, p in enumerate(items.points)}
        # (name, first item, channels, block) of each point of the group
        self.points = [(n, items.first[index[n]], items.points[index[n]].channels,
                        items.points[index[n]].block) for n in self.names]
        self.items = frozenset(k for _, k0, n, _ in self.points for k in range(k0, k0 + n))
        self.lock = threading.Lock()  # the decoders' arrays are shared

    def layout(self) -> dict[str, tuple[int, int, int]]:
        """Table -> (first address, registers, byte offset in the image)."""
        out, off = {}, 0
        for d in self.decoders:
            out[d.table] = (d.address, d.count, off)
            off += 2 * d.count
        return out

    def unread_of(self, names: Iterable[str]) -> frozenset[int]:
        """The items of the group's points ``names`` (a block's every channel)."""
        want = set(names)
        return frozenset(k for n, k0, c, _ in self.points if n in want for k in range(k0, k0 + c))

    def unsupported(self, unread: frozenset[int]) -> tuple[str, ...]:
        """The group's points with an item in ``unread``, in map order."""
        return tuple(n for n, k0, c, _ in self.points if not unread.isdisjoint(range(k0, k0 + c)))

    def decode(self, regs: array[int], unread: frozenset[int]
               ) -> tuple[dict[str, Value], dict[str, Any]]:
        """(values, states) of the group's points from its registers."""
        values: dict[str, Value] = {}
        states: dict[str, Any] = {}
        at = 0
        with self.lock:
            for dec in self.decoders:
                b = dec.decode(regs[at:at + dec.count])
                at += dec.count
                values.update(dec.values(b))
                states.update(dec.states(b))
        for name, k0, channels, block in self.points if unread else ():
            if unread.isdisjoint(range(k0, k0 + channels)):
                continue
            if block:
                v, st = values[name], states[name]
                assert isinstance(v, list)
                for c in range(channels):
                    if k0 + c in unread:
                        v[c], st[c] = None, "unsupported"
            else:
                values[name], states[name] = None, "unsupported"
        return {n: values[n] for n in self.names}, {n: states[n] for n in self.names}


class Blocks:
    """Blocks of ``channels`` float values each, kept as the C decoder left
    them: ``values`` (float64, NaN where there is none) and ``states``
    (uint8 state codes), block after block in the order of ``names``. A
    reading's :attr:`MapReading.values` and :attr:`MapReading.states` are
    views of it (:meth:`value_map`, :meth:`state_map`): the lists are made
    only when asked for (a logger that stores the registers makes none)."""

    __slots__ = ("channels", "index", "names", "states", "values")

    def __init__(self, names: Sequence[str], channels: int, values: array[float],
                 states: array[int], index: Mapping[str, int] | None = None) -> None:
        self.names = tuple(names)
        self.channels = channels
        #: where each block's first channel is in the arrays
        self.index = dict(index) if index is not None else {
            n: i * channels for i, n in enumerate(self.names)}
        self.values = values
        self.states = states

    def value_map(self) -> Mapping[str, Value]:
        """Block name -> its values (None where there is none)."""
        return _BlockView(self, True)

    def state_map(self) -> Mapping[str, Any]:
        """Block name -> its state names."""
        return _BlockView(self, False)


class _BlockView(Mapping[str, Any]):
    __slots__ = ("_values", "blocks")

    def __init__(self, b: Blocks, values: bool) -> None:
        self.blocks, self._values = b, values

    def __getitem__(self, name: str) -> Any:
        b = self.blocks
        at, n = b.index[name], b.channels
        sts = b.states[at:at + n].tolist()
        if not self._values:
            return [STATES[x] for x in sts]
        return [None if st else v for v, st in zip(b.values[at:at + n].tolist(), sts,
                                                    strict=True)]

    def __iter__(self) -> Iterator[str]:
        return iter(self.blocks.names)

    def __len__(self) -> int:
        return len(self.blocks.names)

    def __contains__(self, name: object) -> bool:
        return name in self.blocks.index


@dataclass(frozen=True, init=False)
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

    def __init__(self, map: Map, group: str | None, values: Mapping[str, Value],
                 states: Mapping[str, Any], registers: array[int],
                 unsupported: tuple[str, ...] = (), wire: bytes | None = None) -> None:
        # a logger makes one a poll: its fields go straight into its own
        # __dict__ (the frozen dataclass's __init__ sets each through
        # object.__setattr__, 3x slower); a test checks that this sets every field
        d = self.__dict__
        d["map"] = map
        d["group"] = group
        d["values"] = values
        d["states"] = states
        d["registers"] = registers
        d["unsupported"] = unsupported
        d["wire"] = wire

    @property
    def blocks(self) -> Blocks | None:
        """The :class:`Blocks` ``values`` is a view of, if it is one."""
        v = self.values
        return v.blocks if isinstance(v, _BlockView) else None

    @property
    def channels(self) -> int:
        """0: a map reading has no hub channels."""
        return 0
