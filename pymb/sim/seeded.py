"""The seeded value model of a map device's points that have no ``example``.

A gauge wanders around a seeded level (inside ``valid`` when the map gives
it, else a range its type and scale suggest), a counter counts up from its
level and wraps where its type does, a point with ``values`` takes its
first, a bool a coin toss, text the point's name, flags and bit fields 0.
:class:`~pymb.sim.mapsim.MapSimDevice` puts these values in its registers.
"""

from __future__ import annotations

import math
import random

from pymb.maps import Point
from pymb.maps.types import TYPES

__all__ = ["Wander", "first_value", "value_at"]

#: a moving point's level, swing and phase
Wander = tuple[float, float, float]


def first_value(p: Point, rng: random.Random, sf: int | None) -> tuple[object, Wander | None]:
    """The value ``p`` starts at, drawn from ``rng``, and how it moves
    (None: it stays); ``sf``: the scale factor its ``scale_from`` point has."""
    family = TYPES[p.type].family
    if p.values:
        return next(iter(p.values)), None
    if family in ("bool", "bit"):
        return rng.random() < 0.5, None
    if family == "string":
        return p.name[:(2 if p.string_bytes == "both" else 1) * p.count], None
    if family == "raw":
        return [rng.randrange(0x10000) for _ in range(p.count)], None
    if p.flags or family in ("bits", "half") or p.type == "sunssf":
        return 0, None
    lo, hi = _range(p)
    if p.scale_from is not None and p.valid is None:
        lo, hi = (x * 10.0 ** (sf or 0) for x in (lo, hi))
    level = lo + (hi - lo) * (0.3 + 0.4 * rng.random())
    wander = (level, 0.02 * (hi - lo), rng.random() * 2 * math.pi)
    return fit(p, level), wander


def value_at(p: Point, wander: Wander, t: float, t0: float) -> float | int:
    """The value of a moving point at time ``t`` (its device started at ``t0``)."""
    level, swing, phase = wander
    if p.kind == "counter":
        # counts up from its level, wrapping where the type does
        v = level + swing * (t - t0)
        top = _top(p)
        if v > top:
            v = v % top
    else:
        v = level + swing * math.sin(t / 30.0 + phase)
    return fit(p, v)


def fit(p: Point, v: float) -> float | int:
    """``v`` as the point can hold it: whole for an unscaled integer."""
    if TYPES[p.type].family != "float" and p.scale is None and p.offset is None \
            and p.scale_from is None:
        return round(v)
    return v


def _range(p: Point) -> tuple[float, float]:
    if p.valid is not None:
        return p.valid
    info = TYPES[p.type]
    if info.family == "float":
        lo, hi = 0.0, 100.0
    else:
        raw_lo, raw_hi = info.raw_range()
        lo, hi = max(raw_lo, 0), min(raw_hi, 1000)
    scale, offset = p.scale or 1.0, p.offset or 0.0
    a, b = lo * scale + offset, hi * scale + offset
    return (min(a, b), max(a, b))


def _top(p: Point) -> float:
    """The largest value a counter of ``p``'s type holds, engineering units."""
    info = TYPES[p.type]
    hi = 3.4e38 if info.family == "float" else float(info.raw_range()[1])
    return hi * (p.scale or 1.0) + (p.offset or 0.0)
