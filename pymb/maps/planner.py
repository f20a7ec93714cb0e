"""The read planner: which requests read a set of points in the least wire time.

A device's points (one value each, one or more registers, or one bit) are
planned per table: the planner chooses where the requests start and end.
Its rules are the map contract's ([MAP] 4):

1. a request never splits a point (points that overlap, a status word and
   its bit views, are read together, once);
2. no request exceeds ``max_registers`` (``max_bits`` for coils and discrete
   inputs); ``single_point_requests`` gives one request per point;
3. a request may read registers nobody asked for only where they are known
   to exist: registers of the device's other declared points, and gaps of at
   most ``max_gap`` undeclared registers, inside ``readable`` when the map
   declares it (with ``readable`` and ``max_gap`` unset, any gap inside it);
   never a bridge the device refused before, never a point it refused;
4. among the plans that obey 1-3, the cheapest by :mod:`pymb.wire`'s model
   (request, the silence before the reply or the device's ``turnaround``,
   the reply, and the device's ``inter_request_gap`` before each request).

The plan is exact: dynamic programming over the points sorted by address,
so it is never worse than the naive plan of one request per contiguous run.
:class:`pymb.maps.device_plan.PointPlanner` keeps what one device taught it
(bridges it refused, points it refused alone, retried every ``offline_retry``
seconds).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol

from pymb.errors import InvalidArgument
from pymb.maps.cuts import best_cuts, broken_ties, naive_cost
from pymb.maps.point import MAX_GAP, Limits
from pymb.maps.types import BIT_TABLES, TABLE_FUNCTIONS, TABLES
from pymb.wire import DEFAULT_BAUD, read_bits_time, read_time

__all__ = [
    "BIT_TABLES",
    "MAX_GAP",
    "REPLAN_CODES",
    "TABLES",
    "Item",
    "Known",
    "Limits",
    "Line",
    "ReadPlan",
    "Refusal",
    "Request",
    "on_refusal",
    "plan_points",
    "replans",
]

# What the planner knows of each register (or bit) of a table.
_UNKNOWN, _DECLARED, _READABLE, _REFUSED = 0, 1, 2, 3


@dataclass(frozen=True)
class Line:
    """What a request costs depends on: the line and the device's timing."""

    baudrate: int = DEFAULT_BAUD
    bits_per_char: int = 10
    turnaround: float = 0.0  #: seconds of silence the device needs after a request
    inter_request_gap: float = 0.0  #: seconds of silence before each request

    def __post_init__(self) -> None:
        if self.baudrate <= 0:
            raise InvalidArgument(f"baudrate must be positive, got {self.baudrate!r}")

    def cost(self, table: str, count: int) -> float:
        """Predicted seconds of one read of ``count`` registers (bits) of ``table``."""
        fn = read_bits_time if table in BIT_TABLES else read_time
        return fn(count, self.baudrate, turnaround=self.turnaround, bits=self.bits_per_char,
                  gap=self.inter_request_gap)

    def costs(self, table: str, max_count: int) -> list[float]:
        """``cost(table, n)`` for n = 0..max_count (0 costs nothing): one table,
        not a call per candidate request."""
        return [0.0] + [self.cost(table, n) for n in range(1, max_count + 1)]


@dataclass(frozen=True)
class Item:
    """One point as the planner sees it: where it lives and how wide it is
    (registers; 1 for a bit). A block's channels are an item each."""

    name: str
    table: str
    address: int
    width: int = 1

    @property
    def end(self) -> int:
        """The address after its last register."""
        return self.address + self.width


@dataclass(frozen=True)
class Request:
    """One read: ``count`` registers (bits) of ``table`` from ``address``.

    ``items`` are the indices (into the list that was planned) of the points
    it reads, by address; ``extents`` the groups of overlapping points among
    them, as index tuples; ``bridged`` counts the registers it reads that no
    wanted point needs."""

    table: str
    address: int
    count: int
    items: tuple[int, ...]
    extents: tuple[tuple[int, ...], ...]
    bridged: int

    @property
    def function(self) -> int:
        """The function code that reads it (1 coils, 2 discrete, 3 holding, 4 input)."""
        return TABLE_FUNCTIONS[self.table]


#: the exceptions after which a poll re-plans the refused read (02: illegal
#: data address, 03: illegal data value) when ``split_on_exception`` is on
REPLAN_CODES = frozenset((2, 3))


@dataclass(frozen=True)
class Refusal:
    """What a poll does after the device refused one of its reads: read
    ``requests`` instead, within the same poll; ``unsupported``: the items
    it left out (the device refused them alone: read as unsupported)."""

    requests: tuple[Request, ...]
    unsupported: tuple[int, ...]


class Learner(Protocol):
    """What :func:`on_refusal` asks of a device's planner
    (:class:`pymb.maps.device_plan.PointPlanner`)."""

    @property
    def items(self) -> tuple[Item, ...]: ...

    @property
    def limits(self) -> Limits: ...

    def refuse_bridge(self, request: Request) -> list[tuple[int, int]]: ...

    def replan(self, request: Request) -> ReadPlan: ...

    def mark_unsupported(self, indices: Iterable[int]) -> None: ...

    @property
    def whole_points(self) -> bool: ...

    @property
    def point_of(self) -> tuple[int, ...]: ...


def replans(limits: Limits, code: int) -> bool:
    """Whether a poll re-plans after exception ``code`` (:func:`on_refusal`)
    rather than failing."""
    return code in REPLAN_CODES and limits.split_on_exception


def on_refusal(planner: Learner, request: Request, code: int) -> Refusal | None:
    """The device answered exception ``code`` to ``request``: the one re-plan
    policy of every poller. ``None``: the poll fails (another code, or
    ``split_on_exception`` off). Else, for 02/03: a read that bridged
    registers nobody asked for is planned again without the bridge (never
    bridged again); one of several extents is read extent by extent; the
    points of a single extent are marked unsupported (asked again after
    ``offline_retry``). With the planner's ``whole_points`` (a device that
    has or lacks a block whole, as the sensor hub's firmware does), the
    extents are read point by point instead, and a point refused alone is
    unsupported whole."""
    if not replans(planner.limits, code):
        return None
    if request.bridged and planner.refuse_bridge(request):
        return Refusal(tuple(planner.replan(request).requests), ())
    whole = planner.whole_points and bool(planner.point_of)
    if len(request.extents) > 1:
        items = planner.items
        runs = [request.extents]
        if whole:
            point_of = planner.point_of
            by_point: dict[int, list[tuple[int, ...]]] = {}
            for ext in request.extents:
                by_point.setdefault(point_of[ext[0]], []).append(ext)
            if len(by_point) == 1:
                return _refused_whole(planner, point_of[request.items[0]])
            runs = [tuple(exts) for exts in by_point.values()]
        subs = []
        for run in runs if len(runs) > 1 else [(ext,) for ext in request.extents]:
            ks = tuple(k for ext in run for k in ext)
            start = min(items[k].address for k in ks)
            end = max(items[k].end for k in ks)
            subs.append(Request(request.table, start, end - start, ks, tuple(run), 0))
        return Refusal(tuple(subs), ())
    if whole and len({planner.point_of[k] for k in request.items}) == 1:
        return _refused_whole(planner, planner.point_of[request.items[0]])
    planner.mark_unsupported(request.items)
    return Refusal((), request.items)


def _refused_whole(planner: Learner, point: int) -> Refusal:
    """A point the device refused alone, with ``whole_points``: every item
    of it is unsupported (those this poll read already too)."""
    ks = tuple(k for k, p in enumerate(planner.point_of) if p == point)
    planner.mark_unsupported(ks)
    return Refusal((), ks)


@dataclass(frozen=True)
class ReadPlan:
    """The requests of a plan, with their predicted wire time and that of the
    naive plan (one request per contiguous run, split at the limit)."""

    requests: tuple[Request, ...]
    predicted_s: float
    naive_s: float
    line: Line
    wanted: int  #: points asked for (a block's channels one each)

    @property
    def spans(self) -> tuple[tuple[int, int], ...]:
        """The requests as ``(address, count)``."""
        return tuple((r.address, r.count) for r in self.requests)

    @property
    def registers(self) -> int:
        """Registers (and bits) on the wire, wanted or not."""
        return sum(r.count for r in self.requests)

    @property
    def baudrate(self) -> int:
        """The line speed the plan was priced at."""
        return self.line.baudrate

    @property
    def turnaround(self) -> float:
        """The device's turnaround the plan was priced with."""
        return self.line.turnaround

    @property
    def bits_per_char(self) -> int:
        """Bits of one character on the line (:func:`pymb.wire.bits_per_char`)."""
        return self.line.bits_per_char

    def explain(self) -> str:
        """A table of the plan: one line per request and the totals."""
        line = self.line
        gap = (f", inter-request gap {line.inter_request_gap * 1e3:g} ms"
               if line.inter_request_gap else "")
        bits = sum(r.count for r in self.requests if r.table in BIT_TABLES)
        regs = self.registers - bits
        words = " and ".join([f"{regs} registers"] * (regs > 0 or not bits)
                             + [f"{bits} bits"] * (bits > 0))
        lines = [
            f"read plan at {line.baudrate} bit/s, turnaround {line.turnaround * 1e3:g} ms{gap}: "
            f"{len(self.requests)} request(s), {words} on the wire for {self.wanted} point(s)"
        ]
        for i, r in enumerate(self.requests, 1):
            what = "bits" if r.table in BIT_TABLES else "registers"
            t = line.cost(r.table, r.count)
            lines.append(f"  {i:3d}. {r.table} {what} {r.address}..{r.address + r.count - 1} "
                         f"({r.count}) {t * 1e3:8.2f} ms")
        saved = self.naive_s - self.predicted_s
        lines.append(f"  predicted {self.predicted_s * 1e3:.2f} ms; naive plan "
                     f"{self.naive_s * 1e3:.2f} ms (saves {saved * 1e3:.2f} ms)")
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.explain()

    def __iter__(self) -> Iterator[Request]:
        return iter(self.requests)

    def __len__(self) -> int:
        return len(self.requests)


class Known:
    """What is known of the registers (bits) of one table of one device:
    declared by a point, inside a ``readable`` range, refused, or unknown.
    Covers only the addresses between the first and last it was told of."""

    __slots__ = ("_lo", "_marks", "has_readable")

    def __init__(self, declared: Iterable[tuple[int, int]] = (),
                 readable: Iterable[tuple[int, int]] = (),
                 refused: Iterable[tuple[int, int]] = ()) -> None:
        """Ranges are half-open ``(start, end)``; ``readable`` ones too."""
        declared, readable, refused = list(declared), list(readable), list(refused)
        every = declared + readable + refused
        self.has_readable = bool(readable)
        self._lo = min((a for a, _ in every), default=0)
        hi = max((b for _, b in every), default=0)
        marks = bytearray(max(0, hi - self._lo))
        lo = self._lo
        for a, b in readable:
            marks[a - lo:b - lo] = bytes((_READABLE,)) * (b - a)
        for a, b in declared:
            marks[a - lo:b - lo] = bytes((_DECLARED,)) * (b - a)
        for a, b in refused:
            marks[a - lo:b - lo] = bytes((_REFUSED,)) * (b - a)
        self._marks = marks

    def bridgeable(self, start: int, end: int, max_gap: int | None) -> bool:
        """Whether a request may read registers ``start..end-1`` that no wanted
        point needs (rule 3 of the module's list)."""
        lo, n = self._lo, len(self._marks)
        a, b = max(start, lo), min(end, lo + n)
        seg = self._marks[a - lo:b - lo] if a < b else bytearray()
        outside = (end - start) - len(seg)  # registers it was never told of
        if _REFUSED in seg:
            return False
        undeclared = outside + len(seg) - seg.count(_DECLARED)
        if undeclared == 0:
            return True
        if self.has_readable:
            return outside == 0 and _UNKNOWN not in seg and (
                max_gap is None or undeclared <= max_gap)
        return undeclared <= (max_gap or 0)


def _extents(items: Sequence[Item], order: Sequence[int], max_count: int
             ) -> tuple[list[int], list[int], list[list[int]]]:
    """Wanted points of one table (indices in address order) merged where
    they overlap: starts, ends, and the points of each extent."""
    starts: list[int] = []
    ends: list[int] = []
    members: list[list[int]] = []
    for k in order:
        it = items[k]
        if starts and it.address < ends[-1]:
            ends[-1] = max(ends[-1], it.end)
            members[-1].append(k)
        else:
            starts.append(it.address)
            ends.append(it.end)
            members.append([k])
        if ends[-1] - starts[-1] > max_count:
            names = ", ".join(items[i].name for i in members[-1])
            raise InvalidArgument(
                f"{names} at {it.table} {starts[-1]}..{ends[-1] - 1} take "
                f"{ends[-1] - starts[-1]} {'bits' if it.table in BIT_TABLES else 'registers'}, "
                f"more than one request may read ({max_count}): a request never splits a point")
    return starts, ends, members


def plan_points(items: Sequence[Item], line: Line, limits: Limits | None = None, *,
                wanted: Iterable[int] | None = None,
                known: Mapping[str, Known] | None = None,
                ties: Sequence[tuple[int, int]] = ()) -> ReadPlan:
    """The cheapest plan that reads ``items`` (or the ones whose indices are
    ``wanted``), table by table. ``known``: what each table's registers are
    (default: only the wanted points are known to exist). ``ties``: pairs of
    items read in one request wherever the rules allow it (a value and its
    scale factor): among the plans, the one that separates the fewest pairs
    wins, then the cheapest."""
    limits = limits or Limits()
    chosen = range(len(items)) if wanted is None else sorted(set(wanted))
    by_table: dict[str, list[int]] = {}
    for k in chosen:
        t = items[k].table
        if t not in TABLES:
            raise InvalidArgument(f"{items[k].name}: unknown table {t!r}; use {', '.join(TABLES)}")
        by_table.setdefault(t, []).append(k)
    requests: list[Request] = []
    total = naive = 0.0
    for table in TABLES:
        ks = by_table.get(table)
        if not ks:
            continue
        ks.sort(key=lambda k: (items[k].address, -items[k].width))
        max_count = limits.max_count(table)
        starts, ends, members = _extents(items, ks, max_count)
        m = len(starts)
        if limits.single_point_requests:
            joinable = [False] * m
        else:
            kn = known.get(table) if known is not None else None
            if kn is None:
                kn = Known(zip(starts, ends, strict=True))
            joinable = [ends[k] == starts[k + 1] or kn.bridgeable(ends[k], starts[k + 1],
                                                                  limits.max_gap)
                        for k in range(m - 1)]
        costs = line.costs(table, max_count)
        broken = broken_ties(ties, members, m) if ties else None
        ranges = [(a, b + 1, most) for t, a, b, most in limits.ranges if t == table]
        last, cost = best_cuts(starts, ends, joinable, max_count, costs, broken, ranges)
        total += cost
        naive += naive_cost(starts, ends, max_count, costs, ranges)
        i = 0
        while i < m:
            j = last[i]
            span = ends[j] - starts[i]
            used = sum(ends[k] - starts[k] for k in range(i, j + 1))
            requests.append(Request(
                table, starts[i], span,
                tuple(k for x in range(i, j + 1) for k in members[x]),
                tuple(tuple(members[x]) for x in range(i, j + 1)),
                span - used))
            i = j + 1
    return ReadPlan(tuple(requests), total, naive, line, len(chosen))

