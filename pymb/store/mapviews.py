"""The plain-SQL views of a map device's stored samples, generated from its
map: ``<id>_readings`` (one row per sample of a group, a column per point
that is not a block) and, for a map with blocks, ``<id>_channels`` (one row
per channel and sample, a column per block), ``-`` in the id read as ``_``.

A column is NULL where the sample holds no value of the point: another
group's sample, a point the device refused (``unsupported``), a marker or a
NaN. The decoding rules of the C decoder (types, byte orders, bit fields,
scale and offset) are written out in SQL; floats are made from their sign,
exponent and mantissa with the table ``pow2`` (2**e, exact)."""

from __future__ import annotations

import re
import sqlite3

from pymb.devices.mapreading import group_layout, group_points
from pymb.maps import Map, Point
from pymb.maps.codec import decimal_power
from pymb.maps.types import SF_RANGE, TYPES, permutation
from pymb.store.schema import MAP_UNSUPPORTED_BITS

__all__ = ["create_map_views", "view_names"]

_DIGITS = "'123456789ABCDEF'"
_POW2 = """CREATE TABLE IF NOT EXISTS pow2(e INTEGER PRIMARY KEY, v REAL NOT NULL) WITHOUT ROWID;
INSERT OR IGNORE INTO pow2
  WITH RECURSIVE up(e, v) AS (SELECT 0, 1.0 UNION ALL SELECT e + 1, v * 2 FROM up WHERE e < 1023),
  down(e, v) AS (SELECT -1, 0.5 UNION ALL SELECT e - 1, v / 2 FROM down WHERE e > -1074)
  SELECT e, v FROM up UNION ALL SELECT e, v FROM down"""


def view_names(map_id: str) -> tuple[str, str]:
    """(readings view, channels view) of a map id."""
    base = re.sub(r"[^0-9A-Za-z_]", "_", map_id)
    return f"{base}_readings", f"{base}_channels"


def _byte(pos: str) -> str:
    """The unsigned byte at 0-based SQL position ``pos`` of ``s.registers``."""
    h = f"hex(substr(s.registers, {pos} + 1, 1))"
    return f"(instr({_DIGITS}, substr({h}, 1, 1)) * 16 + instr({_DIGITS}, substr({h}, 2, 1)))"


def _pattern(p: Point, at: str) -> tuple[str, str]:
    """(unsigned value, value with the first byte signed) of the point's
    bytes from byte ``at``, its order applied."""
    n = 2 * p.count
    order = p.order or ("AB" if n == 2 else "")
    perm = permutation(order) if order else tuple(range(n))
    parts = [(_byte(f"{at} + {perm[j]}"), 256 ** (n - 1 - j)) for j in range(n)]
    terms = [f"{b} * {w}" if w > 1 else b for b, w in parts]
    first = parts[0][0]
    signed_first = f"({first} - CASE WHEN {first} >= 128 THEN 256 ELSE 0 END) * {parts[0][1]}"
    return "(" + " + ".join(terms) + ")", "(" + " + ".join([signed_first, *terms[1:]]) + ")"


def _scaled(v: str, p: Point) -> str:
    if p.scale_from is not None:  # scaled by its scale factor, then the offset: _sf_scaled
        return f"(({v}) * 1.0)"
    k = decimal_power(p.scale)
    if k:
        v = f"({v}) / 1e{k}"
    elif p.scale is not None:
        v = f"({v}) * {p.scale!r}"
    if p.offset is not None:
        v = f"({v}) + {p.offset!r}"
    return v if (p.scale is None and p.offset is None) else f"(({v}) * 1.0)"


def _float(u: str, bits: int) -> str:
    exp_bits, man_bits = {16: (5, 10), 32: (8, 23), 64: (11, 52)}[bits]
    bias = (1 << (exp_bits - 1)) - 1
    exp = f"(({u} >> {man_bits}) & {(1 << exp_bits) - 1})"
    man = f"({u} & {(1 << man_bits) - 1})"
    sign = f"(CASE WHEN ({u} >> {bits - 1}) & 1 THEN -1.0 ELSE 1.0 END)"
    if bits == 64:  # >> of a negative 64-bit integer keeps its sign in SQLite
        sign = f"(CASE WHEN {u} < 0 THEN -1.0 ELSE 1.0 END)"
        exp = f"((({u} >> {man_bits}) & {(1 << exp_bits) - 1}))"
    top = (1 << exp_bits) - 1
    return (f"CASE WHEN {exp} = {top} THEN NULL "
            f"WHEN {exp} = 0 THEN {sign} * {man} * (SELECT v FROM pow2 WHERE e = "
            f"{1 - bias - man_bits}) "
            f"ELSE {sign} * ({man} + {1 << man_bits}) * (SELECT v FROM pow2 WHERE e = "
            f"{exp} - {bias + man_bits}) END")


def _text(p: Point, at: str) -> str:
    """A string point's text: its bytes in the order the decoder takes them
    (one or two a register, swapped for BA), cut at the first NUL, as the
    characters of those byte values (exact for ascii and latin-1); where a
    character is not ASCII, NULL for ascii (invalid text, as the decoder
    says) and for utf-8 (SQL cannot check UTF-8: NULL, never a wrong text)."""
    pos = []
    for i in range(p.count):
        hi, lo = f"{at} + {2 * i}", f"{at} + {2 * i + 1}"
        if p.order == "BA":
            hi, lo = lo, hi
        pos += [hi, lo] if p.string_bytes == "both" else \
            [hi if p.string_bytes == "high" else lo]
    k = len(pos)
    octets = ", ".join(f"{_byte(x)} AS b{j}" for j, x in enumerate(pos))
    end = " ".join(f"WHEN b{j} = 0 THEN {j}" for j in range(k))
    # a NUL never goes into the text (SQL's text functions stop at one): it is cut anyway
    chars = " || ".join(
        "char(" + ", ".join(f"b{j} + (b{j} = 0)" for j in range(c, min(c + 100, k))) + ")"
        for c in range(0, k, 100))
    text = f"substr({chars}, 1, CASE {end} ELSE {k} END)"
    out = "t" if p.encoding == "latin-1" else \
        "CASE WHEN t GLOB '*[^' || char(1) || '-' || char(127) || ']*' THEN NULL ELSE t END"
    return f"(SELECT {out} FROM (SELECT {text} AS t FROM (SELECT {octets})))"


def _sf_scaled(v: str, sf: str) -> str:
    """``v`` x 10^sf as the decoder makes it (dividing by 10^-sf for a
    negative one); NULL for a scale factor outside SunSpec's range."""
    lo, hi = SF_RANGE
    cases = " ".join(f"WHEN {k} THEN ({v}) / 1e{-k}" if k < 0 else f"WHEN {k} THEN ({v}) * 1e{k}"
                     for k in range(lo, hi + 1))
    return f"(CASE {sf} {cases} ELSE NULL END)"


def _signed64(r: int) -> int:
    return r - (1 << 64) if r >> 63 else r


def _value(p: Point, at: str, sf_at: str | None = None, sf: Point | None = None) -> str:
    """The SQL of one channel's value from byte ``at`` of the stored
    registers (a ``scale_from`` point: its scale factor ``sf`` at ``sf_at``)."""
    family = TYPES[p.type].family
    if family in ("bool",):
        return f"(CASE WHEN {_byte(at)} * 256 + {_byte(f'{at} + 1')} != 0 THEN 1 ELSE 0 END)"
    if family == "raw":
        return f"hex(substr(s.registers, {at} + 1, {2 * p.count}))"
    if family == "string":
        return _text(p, at)
    u, signed = _pattern(p, at)
    if family == "bit":
        return f"(({u} >> {p.bit or 0}) & 1)"
    if family == "bits":
        u = f"(({u} >> {p.shift or 0}) & {(1 << (p.width or 1)) - 1})"
        signed = u
    elif family == "half":
        u = f"({u} >> 8)" if p.type.endswith("_hi") else f"({u} & 255)"
        signed = f"({u} - CASE WHEN {u} >= 128 THEN 256 ELSE 0 END)" if p.type[0] == "i" else u
    if p.mask is not None:  # u16, u32, u64 only
        u = f"({u} & {_signed64(p.mask)})"
        signed = f"({signed} & {_signed64(p.mask)})"
    if family == "float":
        v = _scaled(_float(u if p.count < 4 else signed, 16 * p.count), p)
    elif family == "sm":
        mag = f"({u} & 32767)"
        v = _scaled(f"(CASE WHEN {u} >= 32768 THEN -{mag} ELSE {mag} END)", p)
    elif p.type == "u64":
        # exact below 2**63; above, the nearest REAL (SQLite has no larger integer)
        v = _scaled(f"(CASE WHEN {signed} >= 0 THEN {signed} ELSE ((({signed} >> 32) & "
                    f"4294967295) * 4294967296.0 + ({signed} & 4294967295)) END)", p)
    else:
        v = _scaled(signed if TYPES[p.type].signed else u, p)
    if p.scale_from is not None and sf is not None and sf_at is not None:
        v = _sf_scaled(v, _pattern(sf, sf_at)[1])
        if p.offset is not None:
            v = f"({v} + {p.offset!r})"
    marker = u if p.count < 4 else signed
    if p.markers:
        raws = ", ".join(str(r) for r in p.markers)
        if p.count == 4:  # the markers of a 64-bit value, as the signed pattern holds them
            raws = ", ".join(str(_signed64(r)) for r in p.markers)
        v = f"CASE WHEN {marker} IN ({raws}) THEN NULL ELSE {v} END"
    if p.marker_masks:
        fix = _signed64 if p.count == 4 else int
        whens = " OR ".join(f"({marker} & {fix(care)}) = {fix(pattern)}"
                            for pattern, care, _ in p.marker_masks)
        v = f"CASE WHEN {whens} THEN NULL ELSE {v} END"
    return v


#: columns the readings view's inner select may add (SQLite allows 2,000 a select)
_INNER_MAX = 1900


def _columns(m: Map, blocks: bool, inner: list[str] | None = None) -> list[str]:
    """Each point's column (blocks or the others), NULL outside its group.
    With ``inner``, each point's pattern (its bytes as an integer, which a
    value's SQL uses several times) is written once, as a column of an
    inner select appended to ``inner``, and the value names it (the view's
    text, which SQLite keeps parsed in memory, several times shorter)."""
    groups: list[str | None] = list(m.groups) if m.groups else [None]
    # name -> (condition, value) for each group that reads it (a scale factor
    # is read by its own group and by those of the points it scales)
    cases: dict[str, list[tuple[str, str]]] = {}
    for g in groups:
        names = group_points(m, g)
        offsets: dict[str, int] = {}
        at = 0
        for dec in group_layout(m, g):
            for n in dec.names:
                offsets[n] = 2 * (at + m.points[n].address - dec.address)
            at += dec.count
        for i, n in enumerate(names):
            p = m.points[n]
            if p.block != blocks:
                continue
            at_sql = str(offsets[n]) if not blocks else \
                f"{offsets[n]} + 2 * {p.stride} * (c.channel - 1)"
            bit = min(i, MAP_UNSUPPORTED_BITS)
            cond = f"g.grp = '{g or ''}' AND NOT (s.unsupported >> {bit}) & 1"
            if blocks:
                cond += f" AND c.channel <= {p.channels}"
            sf = m.points[p.scale_from] if p.scale_from is not None else None
            sf_at = str(offsets[sf.name]) if sf is not None else None
            v = _value(p, at_sql, sf_at, sf)
            if inner is not None and TYPES[p.type].family not in ("raw", "string", "bool"):
                for pattern in reversed(_pattern(p, at_sql)):  # the signed one first
                    if pattern in v and len(inner) < _INNER_MAX:
                        name = f"_p{len(inner)}"
                        inner.append(f"{pattern} AS {name}")
                        v = v.replace(pattern, name)
            cases.setdefault(n, []).append((cond, v))
    return [f"CASE {' '.join(f'WHEN {c} THEN {v}' for c, v in whens)} END AS \"{n}\""
            for n, whens in cases.items()]


def create_map_views(db: sqlite3.Connection, m: Map) -> None:
    """(Re)create the views of map ``m`` (with the options it was logged
    with) and the ``pow2`` table they use, in the open transaction."""
    for stmt in _POW2.split(";\n"):
        db.execute(stmt)
    readings, channels = view_names(m.id)
    head = ("SELECT strftime('%Y-%m-%dT%H:%M:%fZ', s.time_utc, 'unixepoch') AS time, "
            "s.time_utc, d.name AS device, d.address, s.id AS sample_id, g.grp AS grp")
    src = ("FROM samples s JOIN devices d ON d.id = s.device_id "
           "JOIN (SELECT id, substr(humidity_units, 7, instr(humidity_units || ',', ',') - 7) "
           f"AS grp FROM devices WHERE type = '{m.id}') g ON g.id = s.device_id")
    db.execute(f'DROP VIEW IF EXISTS "{readings}"')
    db.execute(f'DROP VIEW IF EXISTS "{channels}"')
    inner: list[str] = []
    cols = _columns(m, False, inner)
    if cols:
        pre = "" if not inner else (
            "(SELECT s.id, s.device_id, s.time_utc, s.registers, s.unsupported, "
            f"{', '.join(inner)} FROM samples s) ")
        db.execute(f"CREATE VIEW \"{readings}\" AS {head}, {', '.join(cols)} "
                   f"{src.replace('FROM samples s ', 'FROM ' + pre + 's ', 1) if pre else src} "
                   "WHERE s.registers IS NOT NULL")
    bcols = _columns(m, True)
    if bcols:
        most = max(p.channels for p in m.points.values() if p.block)
        seq = ", ".join(f"({c})" for c in range(1, most + 1))
        db.execute(f"CREATE VIEW \"{channels}\" AS {head}, c.channel, {', '.join(bcols)} {src} "
                   f"JOIN (SELECT column1 AS channel FROM (VALUES {seq})) c "
                   "WHERE s.registers IS NOT NULL")
