"""Where a plan's requests start and end: the dynamic programme of
:func:`pymb.maps.planner.plan_points` over one table's extents (points
merged where they overlap, sorted by address), with its limits (the
request size, the ranges of ``[device.limits] ranges``) and its tie-break
(pairs read in one request wherever the rules allow)."""

from __future__ import annotations

from collections.abc import Sequence

__all__ = ["best_cuts", "broken_ties", "naive_cost"]


def _reach(i: int, starts: Sequence[int], ends: Sequence[int], joinable: Sequence[bool],
           max_count: int, ranges: Sequence[tuple[int, int, int]] | None) -> int:
    """The last extent a request from extent ``i`` may reach: joinable all
    the way, within ``max_count`` and within every range limit it touches
    (``ranges``: half-open ``(start, end, most)``)."""
    m = len(starts)
    s = starts[i]
    limit = s + max_count
    if ranges:
        limit = min([limit] + [s + most for a, b, most in ranges if a < ends[i] and s < b])
    j = i
    while j + 1 < m and joinable[j] and ends[j + 1] <= limit:
        if ranges:
            e = ends[j + 1]
            cap = min([limit] + [s + most for a, b, most in ranges if a < e and s < b])
            if e > cap:
                break
        j += 1
    return j


def best_cuts(starts: Sequence[int], ends: Sequence[int], joinable: Sequence[bool],
               max_count: int, costs: Sequence[float],
               broken: Sequence[int] | None = None,
               ranges: Sequence[tuple[int, int, int]] | None = None
               ) -> tuple[list[int], float]:
    """The cheapest cut of extents (sorted, disjoint) into requests: for each
    request's first extent ``i``, ``last[i]`` is its last one; and the cost.
    ``joinable[k]``: extents ``k`` and ``k + 1`` may share a request.
    ``broken[k]``: the tied pairs a cut after extent ``k`` separates; with
    it, the plan that separates the fewest wins, then the cheapest.
    ``ranges``: half-open ``(start, end, most)`` range limits."""
    if (broken is not None and any(broken)) or ranges:
        return _best_tied_cuts(starts, ends, joinable, max_count, costs,
                               broken or [0] * len(starts), ranges)
    m = len(starts)
    best = [0.0] * (m + 1)
    last = [0] * m
    for i in range(m - 1, -1, -1):
        limit = starts[i] + max_count
        j = i
        while j + 1 < m and joinable[j] and ends[j + 1] <= limit:
            j += 1
        # Longer first requests are tried first, so among equal plans the one
        # whose requests are full from the start wins (125, 125, ..., rest).
        s = starts[i]
        b = float("inf")
        e = i
        while j >= i:
            c = costs[ends[j] - s] + best[j + 1]
            if c < b - 1e-12:  # ties (up to rounding) keep the longer request
                b, e = c, j
            j -= 1
        best[i], last[i] = b, e
    return last, best[0]


def _best_tied_cuts(starts: Sequence[int], ends: Sequence[int], joinable: Sequence[bool],
                    max_count: int, costs: Sequence[float], broken: Sequence[int],
                    ranges: Sequence[tuple[int, int, int]] | None = None
                    ) -> tuple[list[int], float]:
    """:func:`best_cuts` ordered by (pairs separated, cost), with range limits."""
    m = len(starts)
    best: list[tuple[int, float]] = [(0, 0.0)] * (m + 1)
    last = [0] * m
    for i in range(m - 1, -1, -1):
        j = _reach(i, starts, ends, joinable, max_count, ranges)
        s = starts[i]
        b: tuple[int, float] = (1 << 62, float("inf"))
        e = i
        while j >= i:
            nb, nc = best[j + 1]
            c = (nb + (broken[j] if j + 1 < m else 0), costs[ends[j] - s] + nc)
            if c[0] < b[0] or (c[0] == b[0] and c[1] < b[1] - 1e-12):
                b, e = c, j
            j -= 1
        best[i], last[i] = b, e
    return last, best[0][1]


def naive_cost(starts: Sequence[int], ends: Sequence[int], max_count: int,
                costs: Sequence[float],
                ranges: Sequence[tuple[int, int, int]] | None = None) -> float:
    """One request per contiguous run of extents, split (between extents) at the limit."""
    if ranges:
        m = len(starts)
        contiguous = [ends[k] == starts[k + 1] for k in range(m - 1)]
        total, i = 0.0, 0
        while i < m:
            j = _reach(i, starts, ends, contiguous, max_count, ranges)
            total += costs[ends[j] - starts[i]]
            i = j + 1
        return total
    total, first, prev = 0.0, -1, -1
    for s, e in zip(starts, ends, strict=True):
        if first >= 0 and s == prev and e - first <= max_count:
            prev = e
            continue
        if first >= 0:
            total += costs[prev - first]
        first, prev = s, e
    return total + (costs[prev - first] if first >= 0 else 0.0)


def broken_ties(ties: Sequence[tuple[int, int]], members: Sequence[Sequence[int]], m: int
            ) -> list[int]:
    """For each cut after extent k: the tied pairs (both wanted) it separates."""
    extent = {k: x for x, ks in enumerate(members) for k in ks}
    broken = [0] * m
    for a, b in ties:
        xa, xb = extent.get(a), extent.get(b)
        if xa is None or xb is None or xa == xb:
            continue
        for k in range(min(xa, xb), max(xa, xb)):
            broken[k] += 1
    return broken
