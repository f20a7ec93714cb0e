"""A map's points compiled into ``pymb_map_decode``'s table: one C call
decodes every point of a request into preallocated arrays.

The table and the call are :mod:`pymb._native.mapdecode`'s; this module says
what goes into the table.
"""

from __future__ import annotations

from array import array
from collections.abc import Callable, Iterable, Sequence
from typing import Any

from pymb._native import mapdecode as c
from pymb.errors import InvalidArgument
from pymb.maps.codec import decimal_power
from pymb.maps.model import Map
from pymb.maps.point import MapError, Point, Value
from pymb.maps.types import STATES, TYPES, permutation

__all__ = ["Buffers", "Decoder"]

_U64 = (1 << 64) - 1
#: Types the C decoder knows by another name.
_C_TYPE = {"sunssf": "i16"}


def _markers_of(p: Point) -> int:
    """Entries of the C markers array a point takes: its mask, its markers,
    two for each marker with don't-care bits."""
    return (p.mask is not None) + len(p.markers) + 2 * len(p.marker_masks)
# How a slot becomes a Python value.
_INT, _UINT64, _FLOAT, _BOOL, _TEXT, _RAW = range(6)


def _check_states() -> None:
    """The state codes Python names are the C core's."""
    if any(STATES.index(n) != code for n, code in c.STATE_CODES.items()) or \
            len(STATES) > c.FIRST_MARKER_STATE:
        raise ImportError("pymb.maps.STATES disagrees with the C core's state codes")


_check_states()


class Buffers:
    """One set of output arrays: ``values`` (float64, NaN where no value),
    ``ints`` (int64: exact integers, text lengths), ``states`` (uint8 state
    codes, names in :attr:`Map.state_names`), ``text`` (strings' bytes), and
    ``registers``, the registers last decoded into them."""

    __slots__ = ("_out", "ints", "registers", "states", "text", "values")

    def __init__(self, slots: int, text_bytes: int, *, values: array[float] | None = None,
                 states: array[int] | None = None) -> None:
        # given arrays (a reading's own) are written in place: never resized
        # while these buffers live
        if values is not None and (values.typecode != "d" or len(values) < slots):
            raise InvalidArgument(f"values must be an array('d') of {slots} or more")
        if states is not None and (states.typecode != "B" or len(states) < slots):
            raise InvalidArgument(f"states must be an array('B') of {slots} or more")
        self.values = array("d", bytes(8 * slots)) if values is None else values
        self.ints = array("q", bytes(8 * slots))
        self.states = array("B", bytes(slots)) if states is None else states
        self.text = bytearray(text_bytes)
        self.registers: Sequence[int] = ()
        self._out = c.MapOut(self.values, self.ints, self.states, self.text)


class Decoder:
    """Some points of a map (default: every point of ``table``), compiled for
    requests whose registers start at ``address`` (default: the first point's).

    ``decode(registers)`` is one C call that fills :attr:`buffers` (or the
    :class:`Buffers` given as ``into=``); ``read(registers)`` also builds the
    ``{name: value}`` dict, blocks as lists. ``slot(name)`` is where a point's
    first channel is in the arrays. Points must all be in one table.
    """

    def __init__(self, m: Map, names: Iterable[str] | None = None, *, table: str | None = None,
                 address: int | None = None) -> None:
        if not isinstance(m, Map):
            raise InvalidArgument(f"a decoder needs a map, got {type(m).__name__}")
        if names is None:
            first = table or next(iter(m.points.values())).table
            points = [p for p in m.points.values() if p.table == first]
        else:
            points = [m.point(n) for n in names]
        # a scale_from point's scale factor is decoded with it (one table, by the loader)
        points += [m.points[n] for n in m.with_scale_factors(p.name for p in points)[len(points):]]
        if not points:
            raise MapError(f"{m.source}: no points to decode", source=m.source)
        tables = {p.table for p in points}
        if len(tables) > 1:
            raise MapError(f"{m.source}: one decoder decodes one table, not {sorted(tables)}",
                           source=m.source)
        self.map = m
        self.table = points[0].table
        self.address = min(p.address for p in points) if address is None else address
        if any(p.address < self.address for p in points):
            raise MapError(f"{m.source}: a point starts before address {self.address}",
                           source=m.source)
        #: registers a request must hold, from ``address``
        self.count = max(p.end for p in points) - self.address
        codes = {name: i for i, name in enumerate(m.state_names) if name}
        nmarkers = sum(_markers_of(p) for p in points)
        ctable = c.MapTable(len(points), nmarkers)
        slot = text = mk = 0
        self._plan: list[tuple[str, int, int, int, int, int, str]] = []
        self._slots: dict[str, int] = {}
        for i, p in enumerate(points):
            per = 2 * p.count if p.string_bytes == "both" else p.count
            self._compile(ctable, i, p, slot, text if p.type == "string" else 0, mk)
            # a mask first (PYMB_MAP_MASKED), then exact markers, then patterns
            entry_markers: list[tuple[int, int]] = [(p.mask, 0)] if p.mask is not None else []
            entry_markers += [(raw, codes[state]) for raw, state in p.markers.items()]
            for pattern, care, state in p.marker_masks:
                entry_markers += [(care, c.MARKER_MASK), (pattern, codes[state])]
            for raw, code in entry_markers:
                ctable.marker(mk, raw, code)
                mk += 1
            self._plan.append((p.name, self._kind(p), slot, p.channels, text, per, p.encoding))
            self._slots[p.name] = slot
            if p.type == "string":
                text += per * p.channels
            slot += p.channels
        self.names = tuple(p.name for p in points)
        self.slots = slot
        self._table = ctable
        self._counts = {p.name: p.count for p in points}
        self._blocks = frozenset(p.name for p in points if p.block)
        self._order = [(e[0], e[2], None if e[1] == _FLOAT and e[0] not in self._blocks else e)
                       for e in self._plan]
        self._text_bytes = text
        self.buffers = self.new_buffers()

    def _compile(self, table: c.MapTable, i: int, p: Point, slot: int, text: int,
                 first_marker: int) -> None:
        aux, flags, scale, decimals, offset = text, 0, 0.0, 0, 0.0
        if p.scale_from is not None:
            sf = self.map.points[p.scale_from]
            flags |= c.SCALE_FROM
            aux = (sf.address - self.address) | (c.SF_SWAPPED if sf.order == "BA" else 0)
        if p.mask is not None:
            flags |= c.MASKED
        if p.scale is not None:
            flags |= c.SCALED
            scale, decimals = p.scale, decimal_power(p.scale)
        if p.offset is not None:
            flags |= c.OFFSET
            offset = p.offset
        order: Sequence[int] = ()
        if p.type == "string":
            flags |= c.SWAP if p.order == "BA" else 0
            flags |= {"both": 0, "high": c.HIGH_BYTE, "low": c.LOW_BYTE}[p.string_bytes]
            flags |= c.ASCII if p.encoding == "ascii" else 0
        elif p.order:
            order = permutation(p.order)
        table.entry(i, first=p.address - self.address, out=slot, aux=aux, channels=p.channels,
                    stride=p.stride, count=p.count,
                    type_=c.type_code(_C_TYPE.get(p.type, p.type)), flags=flags,
                    bit=(p.bit or 0) if p.type == "bit" else (p.shift or 0), width=p.width or 0,
                    decimals=decimals, order=order, scale=scale, offset=offset,
                    first_marker=first_marker, nmarkers=_markers_of(p))

    @staticmethod
    def _kind(p: Point) -> int:
        family = TYPES[p.type].family
        if family in ("bool", "bit"):
            return _BOOL
        if family == "string":
            return _TEXT
        if family == "raw":
            return _RAW
        if (family == "float" or p.scale is not None or p.offset is not None
                or p.scale_from is not None):
            return _FLOAT
        return _UINT64 if p.type == "u64" else _INT

    def new_buffers(self) -> Buffers:
        """A fresh set of output arrays for ``decode(..., into=)``."""
        return Buffers(self.slots, self._text_bytes)

    def slot(self, name: str) -> int:
        """Index of the point's first channel in the output arrays."""
        if name not in self._slots:
            self.map.point(name)  # an unknown name: did you mean
            raise MapError(f"{self.map.source}: point {name!r} is not in this decoder",
                           source=self.map.source, point=name)
        return self._slots[name]

    def decode(self, registers: Sequence[int], into: Buffers | None = None) -> Buffers:
        """Decode ``registers`` (from :attr:`address`; an ``array('H')`` is
        taken without a copy) in one C call; returns the buffers written."""
        b = self.buffers if into is None else into
        if not isinstance(registers, array) or registers.typecode != "H":
            try:
                registers = array("H", registers)
            except (OverflowError, TypeError):
                raise InvalidArgument(f"{self.map.id}: registers are whole numbers 0..65535, "
                                      f"got {registers!r:.60}") from None
        if len(registers) < self.count:
            raise InvalidArgument(f"{self.map.id}: {self.count} registers from {self.address} "
                                  f"are needed, got {len(registers)}")
        rc = self._table.decode(registers, b._out)  # noqa: SLF001 - Buffers is this module's
        if rc < 0:  # the table is built here: it cannot be invalid
            raise InvalidArgument(f"{self.map.id}: the compiled map was refused")
        b.registers = registers
        return b

    def bind(self, registers: array[int], into: Buffers | None = None) -> Callable[[], int]:
        """The C call of :meth:`decode` of ``registers`` into :attr:`buffers`
        (or ``into``), its arguments checked once: each call decodes them
        again and returns the number of values written. For a reader that
        decodes the same buffer over and over; while the call lives,
        ``registers`` (an ``array('H')`` of at least :attr:`count` registers)
        cannot change its size, and the caller keeps ``into`` alive (the call
        writes its arrays)."""
        return self.prepare(registers, into).run

    def prepare(self, registers: array[int], into: Buffers | None = None) -> c.MapJob:
        """:meth:`bind`'s decode made ready, as the job it runs: ``run()``
        decodes again, and a read plan given the job decodes once its
        requests have their replies (one C call for both)."""
        if not isinstance(registers, array) or registers.typecode != "H":
            raise InvalidArgument(f"{self.map.id}: bind takes an array('H'), "
                                  f"got {type(registers).__name__}")
        b = self.buffers if into is None else into
        self.decode(registers, b)  # checks the length, and the table once
        return self._table.bind(registers, b._out)  # noqa: SLF001 - this module's

    def read(self, registers: Sequence[int]) -> dict[str, Value]:
        """``{name: value}`` of every point, blocks as lists, None where no value."""
        return self.values(self.decode(registers))

    def values(self, b: Buffers | None = None) -> dict[str, Value]:
        """The dict of the values in ``b`` (default: :attr:`buffers`)."""
        b = self.buffers if b is None else b
        vals, ints, states = b.values.tolist(), b.ints, b.states
        out: dict[str, Value] = {}
        for name, slot, entry in self._order:
            if entry is None:  # the common case: one float, no list
                out[name] = None if states[slot] else vals[slot]
                continue
            _, kind, slot, channels, text, per, encoding = entry
            one: list[Value] = []
            for i in range(slot, slot + channels):
                if states[i]:
                    one.append(None)
                elif kind == _FLOAT:
                    one.append(vals[i])
                elif kind == _INT:
                    one.append(ints[i])
                elif kind == _UINT64:
                    one.append(ints[i] & _U64)
                elif kind == _BOOL:
                    one.append(ints[i] != 0)
                elif kind == _TEXT:
                    at = text + per * (i - slot)
                    try:
                        one.append(bytes(b.text[at:at + ints[i]]).decode(encoding))
                    except UnicodeDecodeError:
                        one.append(None)
                else:
                    at = ints[i]
                    one.append(list(b.registers[at:at + self._counts[name]]))
            out[name] = one if name in self._blocks else one[0]
        return out

    def states(self, b: Buffers | None = None) -> dict[str, Any]:
        """``{name: state name}`` (lists for blocks) of the values in ``b``."""
        b = self.buffers if b is None else b
        names = self.map.state_names
        out: dict[str, Any] = {}
        for name, kind, slot, channels, text, per, encoding in self._plan:
            one = []
            for i in range(slot, slot + channels):
                state = names[b.states[i]]
                if state == "value" and kind == _TEXT:
                    at = text + per * (i - slot)
                    try:
                        bytes(b.text[at:at + b.ints[i]]).decode(encoding)
                    except UnicodeDecodeError:
                        state = "invalid_text"
                one.append(state)
            out[name] = one if name in self._blocks else one[0]
        return out
