"""The bench's ``plan`` section: planning the reads of a 1,000-point map.

The map is a ``pymb.map/1`` text, synthetic and seeded: 1,000 points of
``u16``, ``u32``, ``f32`` and ``f64`` over the holding and input tables, with
gaps of undeclared registers between some, ``max_gap = 8``, part of the input
table declared ``readable``, a 5 ms turnaround and a 2 ms inter-request gap,
priced at 9600 bit/s. It is loaded once; each timed ``Map.plan()`` starts
from a fresh planner (no cache). The table also shows what the plan buys on
the wire: its predicted time against the naive plan's (one request per
contiguous run).
"""

from __future__ import annotations

import random
import statistics
import time
from collections.abc import Callable
from typing import Any

from pymb import maps
from pymb.maps.device_plan import map_planner
from pymb.maps.planner import Item

__all__ = ["TARGET_MS", "run_section", "synthetic_map", "synthetic_points", "targets"]

TARGET_MS = 100.0  #: planning a 1,000-point map
POINTS = 1000


def synthetic_map(n: int = POINTS, seed: int = 0) -> str:
    """The text of a map of ``n`` points over two tables, seeded."""
    rng = random.Random(seed)
    lines = ['schema = "pymb.map/1"', "[device]", 'id = "bench-1000"', 'table = "input"',
             "[device.limits]", "max_gap = 8", "readable = { input = [[0, 1500]] }",
             "[device.timing]", "turnaround = 0.005", "inter_request_gap = 0.002"]
    address = {"holding": 0, "input": 0}
    widths = {"u16": 1, "u32": 2, "f32": 2, "f64": 4}
    for i in range(n):
        table = "holding" if rng.random() < 0.4 else "input"
        kind = rng.choice(("u16", "u16", "u32", "f32", "f32", "f64"))
        lines += ["[[point]]", f'name = "p{i}"', f'table = "{table}"',
                  f"address = {address[table]}", f'type = "{kind}"']
        address[table] += widths[kind] + rng.choice((0, 0, 0, 0, 1, 2, 5, 12, 20))
    return "\n".join(lines) + "\n"


def synthetic_points(n: int = POINTS, seed: int = 0) -> list[Item]:
    """The planner's items of :func:`synthetic_map`."""
    return list(map_planner(maps.loads(synthetic_map(n, seed)))[1].items)


def run_section(repeat: int, say: Callable[[str], None]) -> dict[str, Any]:
    """Time ``repeat`` plans of every point (median), each from a fresh planner."""
    say(f"plan: {POINTS}-point map")
    m = maps.loads(synthetic_map(), source="bench-1000.toml")
    times = []
    plan = None
    for _ in range(max(1, repeat)):
        t0 = time.perf_counter()
        plan = m.plan(baudrate=9600)
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
    """This section's target: (what, goal, measured, unit, met)."""
    ms = section["plan_ms"]
    return [(f"planning a {section['points']}-point map", f"<= {TARGET_MS:g} ms", ms * 1e3,
             "us", ms <= TARGET_MS)]
