"""A batch of rows in PostgreSQL's binary COPY format, made without a Python
object per value where the message allows it.

A plain sample whose values are all numbers (the common case: a meter's
readings) is encoded with one :class:`struct.Struct` call per message: the
struct's format is made once per shape of message (the names of its values,
in order) and the per-row constant parts (the point's name, the field
lengths, the node, device, time and sample) are passed as cached bytes. Any
other message (strings, nulls with their states, a block's channels, a
Sparkplug payload) goes through the general path, one row at a time, with the
same checks as :func:`pymb.collect.rows.plain_rows`.

The columns are sent in the order of :data:`COPY_COLUMNS` (``received`` is the
table's default: the time the transaction started).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable, Iterable, Sequence
from itertools import chain, repeat
from operator import itemgetter

from pymb.collect.rows import BadInput, PlainSample, Row, sample_rows
from pymb.jsonvalue import JsonValue

__all__ = ["COPY_COLUMNS", "CopyBatch"]

#: the columns of a COPY row, in the order they are encoded
COPY_COLUMNS = ("point", "value", "node", "device", "time", "sample", "text", "state")

_HEADER = b"PGCOPY\n\xff\r\n\x00" + struct.pack(">ii", 0, 0)
_TRAILER = struct.pack(">h", -1)
_NULL = struct.pack(">i", -1)
_NCOLS = struct.pack(">h", len(COPY_COLUMNS))
_LEN8 = struct.pack(">i", 8)
_INT8 = struct.Struct(">iq")
_FLOAT8 = struct.Struct(">id")
_PG_EPOCH = 946684800.0  #: 2000-01-01 UTC, PostgreSQL's epoch, in Unix seconds
#: the microseconds PostgreSQL's timestamptz takes: 4713 BC to 294276 AD
_US_MIN, _US_MAX = -211813488000000000, 9223371331200000000
_INT64 = (-(2**63), 2**63 - 1)
_SHAPES_MAX = 256  #: message shapes (struct formats) kept; beyond, the cache starts again


def _text(s: str, what: str) -> bytes:
    """A text field (length and UTF-8); BadInput for what PostgreSQL's text
    cannot hold (NUL, a lone surrogate)."""
    if "\x00" in s:
        raise BadInput(f"{what} holds a NUL character")
    try:
        b = s.encode()
    except UnicodeEncodeError:
        raise BadInput(f"{what} is not valid Unicode (a lone surrogate)") from None
    return struct.pack(">i", len(b)) + b


def _time(t: float) -> tuple[int, bytes]:
    """A timestamptz: Unix seconds as PostgreSQL's microseconds since 2000
    (rounded as its ``to_timestamp`` rounds), and its field."""
    try:
        us = round((t - _PG_EPOCH) * 1e6)
    except (OverflowError, ValueError):
        raise BadInput(f"time {t!r} is not a time") from None
    if not _US_MIN <= us < _US_MAX:
        raise BadInput(f"time {t!r} is out of PostgreSQL's range")
    return us, _INT8.pack(8, us)


def _sample(sample: int | None) -> bytes:
    if sample is None:
        return _NULL
    if not _INT64[0] <= sample <= _INT64[1]:
        raise BadInput(f"sample {sample} does not fit in 64 bits")
    return _INT8.pack(8, sample)


#: a message's (or a row's) place in a batch: node, device, time (µs), its
#: (first) point, its bytes
_Entry = tuple[str, str, int, str, bytes]
#: a shape of message: its struct, the heads of its rows, and the order of its
#: values by point name
_Shape = tuple[struct.Struct, tuple[bytes, ...],
               Callable[[list[JsonValue]], Iterable[JsonValue]], str]


class CopyBatch:
    """Rows for one ``COPY ... FROM STDIN (FORMAT binary)``: add messages, then
    :meth:`data`. A message that raises BadInput adds nothing.

    The rows go in the order (node, device, time, point): every writer and
    every collector takes the rows' keys in that one order, so two of them
    storing the same rows at once wait for each other, never deadlock."""

    def __init__(self) -> None:
        self.entries: list[_Entry] = []
        self.rows = 0  #: rows added
        self.newest: float | None = None  #: the newest time of a row added
        self._shapes: dict[tuple[tuple[str, ...], int], _Shape] = {}
        self._heads: dict[str, bytes] = {}

    def adopt(self, other: CopyBatch) -> None:
        """Take the caches of an earlier batch (formats and names made once)."""
        self._shapes, self._heads = other._shapes, other._heads

    def _head(self, point: str) -> bytes:
        """The start of a row up to its value's length: the column count and
        the point's name."""
        h = self._heads.get(point)
        if h is None:
            if len(self._heads) >= 64 * _SHAPES_MAX:
                self._heads.clear()
            h = self._heads[point] = _NCOLS + _text(point, f"point {point!r:.40}")
        return h

    def add_plain(self, node: str, device: str, s: PlainSample) -> None:
        """The rows of one plain sample; raises BadInput (and adds nothing) when
        a value is not what a sample carries."""
        values = s.values
        try:  # numbers only (a string, null or list fails the sum), all finite
            numbers = bool(values) and math.isfinite(
                sum(values.values()))  # type: ignore[arg-type]  # TypeError: not numbers
        except (TypeError, OverflowError):
            numbers = False
        if numbers:  # the states say nothing of a value that is a number
            us, t = _time(s.time)
            tail = (_text(node, "the node") + _text(device, "the device") + t
                    + _sample(s.sample) + _NULL + _NULL)
            names = tuple(values)
            shape = self._shapes.get((names, len(tail))) or self._shape(names, len(tail))
            try:
                chunk = shape[0].pack(*chain.from_iterable(
                    zip(shape[1], shape[2](list(values.values())), repeat(tail))))
            except (struct.error, OverflowError):  # said by the general path
                pass
            else:
                self.entries.append((node, device, us, shape[3], chunk))
                self.rows += len(names)
                if self.newest is None or s.time > self.newest:
                    self.newest = s.time
                return
        self.add_rows(sample_rows(node, device, s))

    def _shape(self, names: tuple[str, ...], tail: int) -> _Shape:
        order = sorted(range(len(names)), key=names.__getitem__)
        heads = tuple(self._head(names[i]) + _LEN8 for i in order)
        st = struct.Struct(">" + "".join(f"{len(h)}sd{tail}s" for h in heads))
        pick = itemgetter(*order) if len(order) > 1 else (lambda v: v)
        if len(self._shapes) >= _SHAPES_MAX:
            self._shapes.clear()
        shape = self._shapes[(names, tail)] = (st, heads, pick, names[order[0]])
        return shape

    def add_rows(self, rows: Sequence[Row]) -> None:
        """General rows (any value, text or state); raises BadInput (and adds
        nothing) for a row PostgreSQL would refuse."""
        out: list[_Entry] = []
        newest: float | None = None
        for node, device, point, t, value, text, state, sample in rows:
            if value is None:
                v = _NULL
            else:
                if not math.isfinite(value):
                    raise BadInput(f"the value of {point} is not finite")
                v = _FLOAT8.pack(8, value)
            us, tf = _time(t)
            out.append((node, device, us, point, b"".join((
                self._head(point), v, _text(node, "the node"), _text(device, "the device"),
                tf, _sample(sample),
                _NULL if text is None else _text(text, f"the text of {point}"),
                _NULL if state is None else _text(state, f"the state of {point}")))))
            newest = t if newest is None or t > newest else newest
        self.entries.extend(out)
        self.rows += len(out)
        if newest is not None and (self.newest is None or newest > self.newest):
            self.newest = newest

    def data(self) -> bytes:
        """The whole COPY stream: header, rows (in key order), trailer."""
        self.entries.sort()
        return b"".join(chain((_HEADER,), (e[4] for e in self.entries), (_TRAILER,)))
