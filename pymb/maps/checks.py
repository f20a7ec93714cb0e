"""The rules a map's points keep together, checked once they are built:
``scale_from`` and ``view_of`` name points of the map, points share
registers only as views of one another, every point fits a request, and no
two names meet in one column of an export."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping

from pymb.maps.fields import Ctx
from pymb.maps.point import Limits, MapError, Point, did_you_mean
from pymb.maps.types import REGISTER_TABLES

__all__ = ["SCALE_FACTOR_TYPES", "check_channel_names", "check_overlaps", "check_refs",
           "check_widths"]

#: Types that read part of another point's registers.
_VIEWS = frozenset({"bit", "bits", "u8_hi", "u8_lo", "i8_hi", "i8_lo"})
#: The types a ``scale_from`` may name: a one-register signed exponent of 10.
SCALE_FACTOR_TYPES = ("sunssf", "i16")


def check_refs(source: str, points: Mapping[str, Point]) -> None:
    """``scale_from`` and ``view_of`` name points of the same map; a scale
    factor is a plain ``sunssf`` (or ``i16``) point of the same table that
    can be read."""
    for p in points.values():
        for key, ref in (("scale_from", p.scale_from), ("view_of", p.view_of)):
            if ref is not None and ref not in points:
                Ctx(source, p.name).fail(key, f"{key} names no point {ref!r}"
                                         f"{did_you_mean(ref, list(points))}")
        if p.scale_from is None:
            continue
        sf = points[p.scale_from]
        why = (f"is a {sf.type}; a scale factor is a {' or '.join(SCALE_FACTOR_TYPES)} point"
               if sf.type not in SCALE_FACTOR_TYPES else
               "is a [[block]]; a scale factor is one value" if sf.block else
               f"is in the {sf.table} table, the point in {p.table}; both must be in one table"
               if sf.table != p.table else
               "is write-only; a scale factor must be read" if sf.access == "w" else
               "has a scale or offset of its own; a scale factor is a plain exponent"
               if sf.scale is not None or sf.offset is not None else "")
        if why:
            Ctx(source, p.name).fail("scale_from", f"scale_from {sf.name!r} {why}")


def check_overlaps(source: str, points: Iterable[Point]) -> None:
    """Points may share registers only as views of one another: a ``bit``,
    ``bits`` or 8-bit half inside another point, a ``raw`` point over any,
    two points of the same type and order on the same registers, or points
    that say ``view_of`` one another (directly or through a third).
    Anything else is a copy-paste slip (two full-width points of different
    types on one register)."""
    spans: dict[str, list[tuple[int, int, Point, int]]] = {}
    for p in points:
        for c in range(p.channels):
            a = p.address + c * p.stride
            spans.setdefault(p.table, []).append((a, a + p.count, p, c + 1))
    shares: set[str] = set()
    by_name = {p.name: p for p in _spans_points(spans)}
    roots = {n: _root(by_name, n) for n in by_name}
    for table, items in spans.items():
        items.sort(key=lambda s: (s[0], -s[1]))
        active: list[tuple[int, int, Point, int]] = []
        for s in items:
            active = [o for o in active if o[1] > s[0]]
            for o in active:
                if o[2] is s[2]:
                    continue
                shares.update((f"{s[2].name}>{o[2].name}", f"{o[2].name}>{s[2].name}"))
                if not _views(s, o, roots):
                    where = _where(table)
                    hint = (f"; if it is one, say view_of = \"{o[2].name}\"" if not
                            (s[2].type == o[2].type and s[0:2] == o[0:2]) else "")
                    raise MapError(
                        f"{source}: point {s[2].name!r}: key 'address': {where(s)} "
                        f"overlaps {where(o)}; points may overlap only as views of one "
                        f"another{hint}", source=source, point=s[2].name, key="address")
            active.append(s)
    for p in points:
        if p.view_of is not None and f"{p.name}>{p.view_of}" not in shares:
            Ctx(source, p.name).fail("view_of", f"view_of {p.view_of!r}, but the two share no "
                                     "register")


def _spans_points(spans: Mapping[str, list[tuple[int, int, Point, int]]]) -> list[Point]:
    """The points of the spans, once each."""
    return list({id(s[2]): s[2] for items in spans.values() for s in items}.values())


def _root(points: Mapping[str, Point], name: str) -> str:
    """The point ``name`` is a view of, through ``view_of`` (itself if none)."""
    seen = {name}
    p = points[name]
    while p.view_of is not None and p.view_of in points and p.view_of not in seen:
        seen.add(p.view_of)
        p = points[p.view_of]
    return p.name


def _views(s: tuple[int, int, Point, int], o: tuple[int, int, Point, int],
           roots: Mapping[str, str]) -> bool:
    """Whether two overlapping channels may share their registers."""
    p, q = s[2], o[2]
    if (p.view_of is not None or q.view_of is not None) and roots[p.name] == roots[q.name]:
        return True
    if "raw" in (p.type, q.type):  # the registers as they are: a view of anything
        return True
    if (s[0], s[1]) == (o[0], o[1]) and p.type == q.type and p.order == q.order:
        return True
    inside = (p.type in _VIEWS and o[0] <= s[0] and s[1] <= o[1]) or (
        q.type in _VIEWS and s[0] <= o[0] and o[1] <= s[1])
    return inside


def check_widths(source: str, limits: Limits, points: Iterable[Point]) -> None:
    """Every point fits one request: a point (a block's channel) wider than
    ``max_registers`` (``max_bits``), or than a range limit where it lies,
    could never be read."""
    for p in points:
        for table, first, last, most in limits.ranges:
            for c in range(1, p.channels + 1):
                a = p.address_of(c)
                if p.table == table and a <= last and first < a + p.count and p.count > most:
                    Ctx(source, p.name).fail(
                        "ranges", f"the point is {p.count} registers ({p.type}) but "
                        f"[device.limits] ranges allow {most} a request at {table} "
                        f"{first}..{last}; it could never be read")
        regs = p.table in REGISTER_TABLES
        key, most = ("max_registers", limits.max_registers) if regs else \
            ("max_bits", limits.max_bits)
        if p.count > most:
            what = "registers" if regs else "bits"
            Ctx(source, p.name).fail(key, f"the point is {p.count} {what} ({p.type}) but "
                                     f"[device.limits] {key} = {most} allows at most {most} "
                                     f"per request; raise {key} to at least {p.count}")


def check_channel_names(source: str, points: Mapping[str, Point]) -> None:
    """A point may not be named as a block's channel is in exports and
    InfluxDB (``t_1`` beside a block ``t``), nor as InfluxDB's field of a
    column without a value (``x_state`` beside ``x``): two values would share
    a column."""
    columns: dict[str, str] = {}  # column -> what it is, for the message
    for b in points.values():
        if b.block:
            for c in range(1, b.channels + 1):
                name = f"{b.name}_{c}"
                if name in points:
                    Ctx(source, name).fail(
                        "name", f"the name {name!r} is channel {c} of block {b.name!r} "
                        f"in exports and InfluxDB ({b.name}_1..{b.name}_{b.channels}); "
                        f"rename the point or the block")
                columns[name] = f"channel {c} of block {b.name!r}"
        else:
            columns[b.name] = f"point {b.name!r}"
    folded: dict[str, str] = {}
    for col, what in columns.items():
        other = folded.setdefault(col.casefold(), col)
        if other != col:
            Ctx(source, col).fail("name", f"{what} and {columns[other]} differ only in case; "
                                  "SQL columns and InfluxDB fields do not tell them apart")
    for col, what in columns.items():
        if f"{col}_state" in points:
            Ctx(source, f"{col}_state").fail(
                "name", f"the name '{col}_state' is the InfluxDB field that says why "
                f"{what} has no value; rename the point")


def _where(table: str) -> Callable[[tuple[int, int, Point, int]], str]:
    def where(x: tuple[int, int, Point, int]) -> str:
        ch = f" channel {x[3]}" if x[2].block else ""
        return f"{x[2].name!r}{ch} ({table} {x[0]}..{x[1] - 1})"
    return where
