"""The C map decoder (``pymb_map.h``): the table a map compiles into, the
output arrays it writes, and the one call that decodes a request's
registers. :mod:`pymb.maps` says what goes into the table; this module is
where it meets cffi.
"""

from __future__ import annotations

from array import array
from collections.abc import Callable, Sequence
from functools import partial
from typing import Any

from pymb._pymb_cffi import ffi, lib

__all__ = [
    "ASCII",
    "FIRST_MARKER_STATE",
    "HIGH_BYTE",
    "LOW_BYTE",
    "MARKER_MASK",
    "MASKED",
    "OFFSET",
    "SCALED",
    "SCALE_FROM",
    "SF_SWAPPED",
    "STATE_CODES",
    "SWAP",
    "MapJob",
    "MapOut",
    "MapTable",
    "type_code",
]

#: The C core's codes of the states it writes beside a value (``pymb_state``
#: and pymb_map.h's own); a map's marker names take codes from
#: :data:`FIRST_MARKER_STATE` up.
STATE_CODES: dict[str, int] = {
    "value": int(lib.PYMB_VALUE), "offline": int(lib.PYMB_OFFLINE),
    "no_sensor": int(lib.PYMB_NO_SENSOR), "unsupported": int(lib.PYMB_UNSUPPORTED),
    "not_read": int(lib.PYMB_NOT_READ), "nan": int(lib.PYMB_MAP_NAN),
    "invalid_text": int(lib.PYMB_MAP_INVALID_TEXT), "no_scale": int(lib.PYMB_MAP_NO_SCALE),
}
FIRST_MARKER_STATE = int(lib.PYMB_MAP_FIRST_MARKER_STATE)
#: In the markers array: the state of a care mask, for the marker after it.
MARKER_MASK = int(lib.PYMB_MAP_MARKER_MASK)

# Entry flags (pymb_map.h).
SCALED = int(lib.PYMB_MAP_SCALED)
OFFSET = int(lib.PYMB_MAP_OFFSET)
SWAP = int(lib.PYMB_MAP_SWAP)
HIGH_BYTE = int(lib.PYMB_MAP_HIGH_BYTE)
LOW_BYTE = int(lib.PYMB_MAP_LOW_BYTE)
ASCII = int(lib.PYMB_MAP_ASCII)
SCALE_FROM = int(lib.PYMB_MAP_SCALE_FROM)
MASKED = int(lib.PYMB_MAP_MASKED)
#: In an entry's ``aux`` with :data:`SCALE_FROM`: the scale factor's bytes swapped.
SF_SWAPPED = int(lib.PYMB_MAP_SF_SWAPPED)


def type_code(name: str) -> int:
    """The C core's code of a value type as the C decoder names it ("u16",
    "f32", "sm16", ...)."""
    return int(getattr(lib, f"PYMB_MAP_{name.upper()}"))


class MapOut:
    """A ``pymb_map_out`` over caller-owned arrays: ``values`` (``array('d')``),
    ``ints`` (``array('q')``), ``states`` (``array('B')``), ``text``
    (``bytearray``), kept alive with it. The arrays must not change size
    while it lives."""

    __slots__ = ("_keep", "cdata")

    def __init__(self, values: array[float], ints: array[int], states: array[int],
                 text: bytearray) -> None:
        out = ffi.new("pymb_map_out *")
        keep = [ffi.from_buffer("double[]", values), ffi.from_buffer("int64_t[]", ints),
                ffi.from_buffer("uint8_t[]", states), ffi.from_buffer("uint8_t[]", text)]
        out.values, out.ints, out.states, out.text = keep
        out.len = min(len(values), len(ints), len(states))
        out.text_len = len(text)
        self.cdata: Any = out
        self._keep = keep


class MapTable:
    """``n`` entries (one a point or block) and ``nmarkers`` markers, zeroed,
    filled by :meth:`entry` and :meth:`marker`; :meth:`decode` runs
    ``pymb_map_decode`` over them."""

    __slots__ = ("_entries", "_markers", "n", "nmarkers")

    def __init__(self, n: int, nmarkers: int) -> None:
        self._entries: Any = ffi.new("pymb_map_entry[]", n)
        self._markers: Any = ffi.new("pymb_map_marker[]", max(nmarkers, 1))
        self.n = n
        self.nmarkers = nmarkers

    def entry(self, i: int, *, first: int, out: int, aux: int, channels: int, stride: int,
              count: int, type_: int, flags: int, bit: int, width: int, decimals: int,
              order: Sequence[int], scale: float, offset: float, first_marker: int,
              nmarkers: int) -> None:
        """Fill entry ``i`` (the fields of ``pymb_map_entry``; ``order`` may be
        empty for a type that has none)."""
        e = self._entries[i]
        e.first, e.out, e.aux = first, out, aux
        e.channels, e.stride, e.count = channels, stride, count
        e.first_marker, e.nmarkers = first_marker, nmarkers
        e.type, e.flags, e.bit, e.width, e.decimals = type_, flags, bit, width, decimals
        for k, pos in enumerate(order):
            e.order[k] = pos
        e.scale, e.offset = scale, offset

    def marker(self, k: int, raw: int, state: int) -> None:
        """Set marker ``k``: the raw value (or care mask) and its state."""
        self._markers[k].raw, self._markers[k].state = raw, state

    def decode(self, registers: array[int], out: MapOut) -> int:
        """Decode ``registers`` (an ``array('H')``) into ``out``: the number
        of values written, or -1 when C refuses the table or the sizes."""
        return int(lib.pymb_map_decode(self._entries, self.n, self._markers, self.nmarkers,
                                       ffi.from_buffer("uint16_t[]", registers),
                                       len(registers), out.cdata))

    def bind(self, registers: array[int], out: MapOut) -> MapJob:
        """:meth:`decode` of ``registers`` into ``out`` made ready: the table
        and the sizes checked once (``pymbi_map_ready``, which decodes once),
        then each :attr:`MapJob.run` decodes them again in one C call with no
        argument (``pymbi_map_run``), as does a read plan given the job. For a
        reader that decodes the same buffer again and again: ``registers``
        cannot change its size while the job lives (it holds the buffer), nor
        the table its entries. Raises ValueError when C refuses the table or
        the sizes."""
        return MapJob(self, registers, out)


class MapJob:
    """A decode made ready (:meth:`MapTable.bind`): :attr:`run` decodes the
    registers again; :attr:`cdata` is the job a read plan decodes once its
    requests have their replies (:class:`pymb._native.link.RegisterPlan`)."""

    __slots__ = ("_keep", "cdata", "run")

    def __init__(self, table: MapTable, registers: array[int], out: MapOut) -> None:
        job = ffi.new("pymbi_map_job *")
        regs = ffi.from_buffer("uint16_t[]", registers)
        job.entries, job.nentries = table._entries, table.n  # noqa: SLF001 - this module's
        job.markers, job.nmarkers = table._markers, table.nmarkers  # noqa: SLF001
        job.regs, job.nregs = regs, len(registers)
        job.out = out.cdata[0]
        if lib.pymbi_map_ready(job) < 0:
            raise ValueError("the map decoder refused the table or the sizes")
        self.cdata: Any = job
        run = partial(lib.pymbi_map_run, job)
        # what the job points into lives as long as the call (which may
        # outlive this object) and this object
        run.keep = self._keep = (table, regs, out)  # type: ignore[attr-defined]
        #: decode again: the slots written
        self.run: Callable[[], int] = run
