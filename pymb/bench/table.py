"""The bench's tables: one titled table, and the formats of its cells. A leaf
that every section's table-maker and the report (which renders them) import,
so the arrows run one way."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

__all__ = ["Table", "X", "fmt_time", "fmt_x", "percentile"]

X = "\N{MULTIPLICATION SIGN}"


@dataclass
class Table:
    """A titled table; ``right`` marks the right-aligned (numeric) columns."""

    title: str
    note: str
    headers: Sequence[str]
    rows: list[list[str]]
    right: Sequence[bool]
    footer: list[str]


def fmt_time(us: float | None) -> str:
    """Microseconds, in the unit that reads best."""
    if us is None or math.isnan(us):
        return "-"
    if us >= 1e6:
        return f"{us / 1e6:.3g} s"
    if us >= 1e3:
        return f"{us / 1e3:.3g} ms"
    if us >= 10:
        return f"{us:.0f} µs"
    return f"{us:.2g} µs"


def fmt_x(x: float | None) -> str:
    """A ratio."""
    if x is None or math.isnan(x):
        return "-"
    if math.isinf(x):
        return "inf"
    return f"{x:.2f}{X}" if x < 10 else f"{x:.1f}{X}" if x < 100 else f"{x:.0f}{X}"


def percentile(values: Sequence[float], q: float) -> float:
    """The value below which a fraction ``q`` (0..1) of ``values`` lie (nearest
    rank, the largest for q = 1); ``values`` must not be empty."""
    s = sorted(values)
    return s[min(len(s) - 1, int(q * len(s)))]
