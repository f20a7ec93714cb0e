"""The read planner: which requests read a set of registers in the least
wire time.

A request for ``n`` registers costs, on an RTU line, the request frame (8
bytes), the silence before the reply (3.5 characters or the device's
turnaround, whichever is longer) and the reply (5 + 2n bytes): the model of
:mod:`pymb.wire`, the one every part of pymb uses. Reading
a few registers nobody asked for between two wanted runs can be cheaper than a
second request; a request never exceeds 125 registers and never crosses a
register the device may not have. The plan is exact (dynamic programming over
the wanted addresses), so it is never worse than the naive plan of one
request per contiguous run.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

from pymb.wire import read_time

__all__ = ["ReadPlan", "naive_spans", "plan_reads"]


@dataclass(frozen=True)
class ReadPlan:
    """Requests as (address, count), with their predicted wire time and that
    of the naive plan (one request per contiguous run, split at the limit)."""

    spans: tuple[tuple[int, int], ...]
    predicted_s: float
    naive_s: float
    baudrate: int
    turnaround: float
    wanted: int  #: registers asked for
    bits_per_char: int = 10  #: the line's character (:func:`pymb.wire.bits_per_char`)

    @property
    def registers(self) -> int:
        """Registers on the wire, wanted or not."""
        return sum(c for _, c in self.spans)

    def explain(self) -> str:
        """A table of the plan: one line per request and the totals."""
        lines = [
            f"read plan at {self.baudrate} bit/s, turnaround {self.turnaround * 1e3:g} ms: "
            f"{len(self.spans)} request(s), {self.registers} registers on the wire for "
            f"{self.wanted} wanted"
        ]
        for i, (address, count) in enumerate(self.spans, 1):
            t = read_time(count, self.baudrate, turnaround=self.turnaround,
                          bits=self.bits_per_char)
            lines.append(f"  {i:3d}. registers {address}..{address + count - 1} "
                         f"({count}) {t * 1e3:8.2f} ms")
        saved = self.naive_s - self.predicted_s
        lines.append(f"  predicted {self.predicted_s * 1e3:.2f} ms; naive plan "
                     f"{self.naive_s * 1e3:.2f} ms (saves {saved * 1e3:.2f} ms)")
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.explain()


def naive_spans(wanted: Iterable[int], max_count: int = 125) -> list[tuple[int, int]]:
    """One request per contiguous run of ``wanted``, split at ``max_count``."""
    spans: list[tuple[int, int]] = []
    for a in sorted(set(wanted)):
        if spans and spans[-1][0] + spans[-1][1] == a and spans[-1][1] < max_count:
            spans[-1] = (spans[-1][0], spans[-1][1] + 1)
        else:
            spans.append((a, 1))
    return spans


def plan_reads(
    wanted: Iterable[int],
    baudrate: int,
    *,
    readable: Callable[[int], bool] = lambda a: True,
    turnaround: float = 0.0,
    max_count: int = 125,
    bits_per_char: int = 10,
) -> ReadPlan:
    """The plan with the least predicted wire time for ``wanted`` addresses.

    ``readable(address)`` says whether a register that was not asked for may
    be read anyway to merge two requests (registers a device lacks are not).
    """
    w = sorted(set(wanted))
    if not w:
        return ReadPlan((), 0.0, 0.0, baudrate, turnaround, 0, bits_per_char)
    if baudrate <= 0 or max_count < 1:
        raise ValueError("baudrate and max_count must be positive")

    # A request's cost depends only on its length: one table, not a call per
    # candidate (a full hub sweep tries ~87,000 of them).
    costs = [0.0] + [read_time(n, baudrate, turnaround=turnaround, bits=bits_per_char)
                     for n in range(1, max_count + 1)]

    # blocked[k]: registers that may not be read lie strictly between w[k] and w[k+1].
    m = len(w)
    blocked = [
        any(not readable(a) for a in range(w[k] + 1, w[k + 1])) for k in range(m - 1)
    ] + [True]
    # best[i]: least cost of reading w[i:]; a request covers w[i..j]. Longer
    # first requests are tried first, so among equal plans the one whose
    # requests are full from the start wins (125, 125, ..., rest).
    best = [0.0] * (m + 1)
    end = [0] * m
    for i in range(m - 1, -1, -1):
        j = i
        while j + 1 < m and not blocked[j] and w[j + 1] - w[i] + 1 <= max_count:
            j += 1
        best[i] = float("inf")
        while j >= i:
            c = costs[w[j] - w[i] + 1] + best[j + 1]
            if c < best[i] - 1e-12:  # ties (up to rounding) keep the longer request
                best[i], end[i] = c, j
            j -= 1
    spans: list[tuple[int, int]] = []
    i = 0
    while i < m:
        j = end[i]
        spans.append((w[i], w[j] - w[i] + 1))
        i = j + 1
    naive = sum(costs[c] for _, c in naive_spans(w, max_count))
    return ReadPlan(tuple(spans), best[0], naive, baudrate, turnaround, m, bits_per_char)
