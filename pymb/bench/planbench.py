"""The bench's ``plan`` section: planning the reads of a 1,000-point map.

The map is synthetic and seeded: 1,000 points of 1, 2 and 4 registers over
the holding and input tables, with gaps of undeclared registers between
some, ``max_gap = 8``, part of the input table declared ``readable``, at
9600 bit/s with a 5 ms turnaround and a 2 ms inter-request gap. Each timed
plan starts from a fresh :class:`~pymb.maps.planner.PointPlanner` (no
cache). The table also shows what the plan buys on the wire: its predicted
time against the naive plan's (one request per contiguous run).
"""

from __future__ import annotations

import random
import statistics
import time
from collections.abc import Callable
from typing import Any

from pymb.maps.planner import Item, Limits, Line, PointPlanner

__all__ = ["TARGET_MS", "run_section", "synthetic_points", "targets"]

TARGET_MS = 100.0  #: planning a 1,000-point map
POINTS = 1000


def synthetic_points(n: int = POINTS, seed: int = 0) -> list[Item]:
    """``n`` points over two tables, seeded: widths 1, 2, 4 and gaps 0..20."""
    rng = random.Random(seed)
    items = []
    address = {"holding": 0, "input": 0}
    for i in range(n):
        table = "holding" if rng.random() < 0.4 else "input"
        width = rng.choice((1, 1, 2, 2, 2, 4))
        items.append(Item(f"p{i}", table, address[table], width))
        address[table] += width + rng.choice((0, 0, 0, 0, 1, 2, 5, 12, 20))
    return items


def _planner(items: list[Item]) -> PointPlanner:
    limits = Limits(max_gap=8, readable={"input": [(0, 1500)]})
    return PointPlanner(items, limits, Line(9600, 10, 0.005, 0.002))


def run_section(repeat: int, say: Callable[[str], None]) -> dict[str, Any]:
    """Time ``repeat`` plans of every point (median), each from a fresh planner."""
    say(f"plan: {POINTS}-point map")
    items = synthetic_points()
    times = []
    plan = None
    for _ in range(max(1, repeat)):
        t0 = time.perf_counter()
        plan = _planner(items).plan()
        times.append(time.perf_counter() - t0)
    assert plan is not None
    return {
        "points": POINTS,
        "repeat": len(times),
        "plan_ms": statistics.median(times) * 1e3,
        "requests": len(plan.requests),
        "registers": plan.registers,
        "predicted_ms": plan.predicted_s * 1e3,
        "naive_ms": plan.naive_s * 1e3,
        "target_ms": TARGET_MS,
    }


def targets(section: dict[str, Any]) -> list[tuple[str, str, float, str, bool]]:
    """The issue's target for this section: (what, goal, measured, unit, met)."""
    ms = section["plan_ms"]
    return [(f"planning a {section['points']}-point map", f"<= {TARGET_MS:g} ms", ms * 1e3,
             "us", ms <= TARGET_MS)]
