"""A reading of a map device as text: a table of ``name  value unit`` lines
and a JSON document (``pymb read``, ``pymb watch``); and the two compact
forms of a reading, each a rule over the map's data: the points of an
indexed array (blocks of as many channels) as one table, a row an index and
a column a quantity (:func:`table_text`), any other as a line a point
labelled by its description (:func:`labelled_text`)."""

from __future__ import annotations

import json
import math
import struct
from collections.abc import Iterable, Mapping
from decimal import Decimal
from typing import Any

from pymb.jsonvalue import nan_to_null
from pymb.maps import Map
from pymb.maps.point import Point

__all__ = ["indexed", "labelled_text", "map_json", "number_text", "printable", "reading_text",
           "render_map", "table_text"]


def printable(value: object) -> str:
    """``value`` as text for a terminal: a device's text with each character
    that is not printable (a control character, the ESC that starts a
    terminal's escape sequence) shown as its escape (``\\x1b``), so what a
    device holds cannot move the cursor, clear the screen or retitle the
    window. The data (stored, exported, JSON) keep the text as it came."""
    text = str(value)
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else c.encode("unicode_escape").decode("ascii")
                   for c in text)


def _decimals(x: float | None) -> int:
    """Decimal places of a map's ``scale`` or ``offset`` as written (0.1: 1, 0.25: 2)."""
    if x is None or not math.isfinite(x):
        return 0
    exponent = Decimal(repr(x)).normalize().as_tuple().exponent
    return min(17, -exponent) if isinstance(exponent, int) and exponent < 0 else 0


def _shortest(value: float, kind: str) -> str:
    """The fewest digits that give ``value`` back in its type (an ``f32``'s
    7 or so, a double's up to 17), written without an exponent unless the
    number is huge or tiny."""
    text = repr(value)
    if kind in ("f32", "f16") and math.isfinite(value):
        code = "e" if kind == "f16" else "f"
        want = struct.pack(f"<{code}", value)
        for n in range(1, 10):
            text = f"{value:.{n}g}"
            try:
                if struct.pack(f"<{code}", float(text)) == want:
                    break
            except OverflowError:  # rounded up past the type's largest
                continue
    if value != 0 and not 1e-6 <= abs(value) < 1e16:
        return text
    return format(Decimal(text), "f")


def number_text(p: Point, value: float) -> str:
    """A point's float as the digits it has: ``precision`` decimals when the
    map gives them; else as many as its ``scale`` and ``offset`` have (a
    scale of 0.1: one); else the shortest that its type gives back
    (123456.7 as an ``f32``, never rounded to 6 significant digits)."""
    if not math.isfinite(value):
        return str(value)
    if p.precision is not None:
        return f"{value:.{p.precision}f}"
    if p.scale is not None or p.offset is not None:
        return f"{value:.{max(_decimals(p.scale), _decimals(p.offset))}f}"
    return _shortest(value, p.type)


def _text(m: Map, name: str, value: Any, state: Any) -> str:
    p = m.points[name]
    if value is None:
        return str(state).replace("_", " ")
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        text = number_text(p, value)
    elif isinstance(value, int) and p.values and value in p.values:
        text = f"{value} ({p.values[value]})"
    elif isinstance(value, int) and p.flags:
        names = [n for bit, n in sorted(p.flags.items()) if value >> bit & 1]
        text = f"0x{value:04X}" + (f" ({', '.join(names)})" if names else "")
    else:
        text = printable(value)
    return f"{text} {p.unit}".rstrip()


def render_map(m: Map, values: Mapping[str, Any], states: Mapping[str, Any]) -> str:
    """A reading as lines ``name  value unit``; a block as one line per channel."""
    rows: list[tuple[str, str]] = []
    for name, v in values.items():
        s = states.get(name)
        if isinstance(v, list) and m.points[name].block:
            for c, (cv, cs) in enumerate(zip(v, s or [None] * len(v), strict=True), 1):
                rows.append((f"{name}[{c}]", _text(m, name, cv, cs)))
        else:
            rows.append((name, _text(m, name, v, s)))
    width = max((len(n) for n, _ in rows), default=0)
    return "\n".join(f"{n:<{width}}  {t}" for n, t in rows)


def map_json(values: Mapping[str, Any], states: Mapping[str, Any]) -> dict[str, Any]:
    """A reading for JSON: values (None where there is none) and their states."""
    out = {"values": nan_to_null(dict(values)),
           "states": dict(states)}
    json.dumps(out, allow_nan=False)  # fails here, not half-way through printing
    return out


def indexed(m: Map, names: Iterable[str]) -> bool:
    """Whether the points ``names`` of ``m`` form one indexed array: each a
    block, all of one channel count."""
    ps = [m.points[n] for n in names]
    return bool(ps) and all(p.block for p in ps) and len({p.channels for p in ps}) == 1


def _quantity(p: Point) -> str:
    """A column's head: the point's name without its unit's suffix, and the unit."""
    return f"{p.name.rsplit('_', 1)[0]} [{p.unit}]"


def table_text(m: Map, values: Mapping[str, Any], states: Mapping[str, Any],
               unsupported: Iterable[str] = ()) -> str:
    """The blocks of an indexed array (:func:`indexed`) as a table: a row a
    channel (numbered from 1), a column a block in the map's order, a
    channel without a value by its state; then the blocks the device's
    firmware lacks, if any."""
    names = [n for n in m.points if n in values]
    rows = [["ch"] + [_quantity(m.points[n]) for n in names]]
    for ch in range(len(values[names[0]])):
        row = [str(ch + 1)]
        for n in names:
            st = states[n][ch]
            row.append(f"{values[n][ch]:g}" if st == "value" else st.replace("_", " "))
        rows.append(row)
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    lines = ["  ".join(cell.rjust(w) for cell, w in zip(r, widths, strict=True))
             for r in rows]
    if unsupported:
        lines.append(f"not supported by this firmware: {', '.join(sorted(unsupported))}")
    return "\n".join(lines)


def _labelled(p: Point, value: Any, state: Any) -> str:
    if value is None or state not in (None, "value"):
        return str(state).replace("_", " ")
    if p.flags:
        raw = int(value)
        names = [n for bit, n in sorted(p.flags.items()) if raw >> bit & 1]
        text = f"0x{raw:04X}" + (f" ({', '.join(names)})" if names else " (ok)")
        undeclared = raw & ~sum(1 << bit for bit in p.flags)
        return text + (f" reserved bits 0x{undeclared:04X}" if undeclared else "")
    if isinstance(value, float):
        text = number_text(p, value)
    elif isinstance(value, int) and p.values and value in p.values:
        text = f"{value} ({p.values[value]})"
    else:
        text = printable(value)
    return f"{text} {p.unit}".strip()


def labelled_text(m: Map, values: Mapping[str, Any], states: Mapping[str, Any]) -> str:
    """Points as lines ``Label  value unit``, in the map's order: the label
    the first words of the point's description, a number with the digits
    :func:`number_text` gives it, a bit field as its raw value and the names of the bits
    set (``ok`` for none; undeclared bits set as ``reserved bits``)."""
    lines = []
    for n in (n for n in m.points if n in values):
        p = m.points[n]
        label = (p.description or n).split(" (")[0].split(",")[0]
        lines.append(f"{label:<16} {_labelled(p, values[n], states.get(n))}")
    return "\n".join(lines)


def reading_text(m: Map, values: Mapping[str, Any], states: Mapping[str, Any],
                 unsupported: Iterable[str] = ()) -> str:
    """A reading's compact form: :func:`table_text` for an indexed array,
    else :func:`labelled_text`."""
    if indexed(m, values):
        return table_text(m, values, states, unsupported)
    return labelled_text(m, values, states)
