"""The planner of one device: what it taught pymb, and a map's points as
planner items.

:class:`PointPlanner` plans with :func:`pymb.maps.planner.plan_points` and
remembers what the device refused: bridges (registers nobody asked for that
it answered exception 02/03 to) are never read again, points it refused
alone are left out for ``offline_retry`` seconds. :func:`map_planner` makes
one for a :class:`~pymb.maps.Map`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

from pymb.maps.planner import Item, Known, Line, ReadPlan, Request, plan_points
from pymb.maps.point import Limits, Point, Points

__all__ = ["MapItems", "PointPlanner", "map_planner"]

_CACHED = 64  #: plans kept per device (groups and selections read)


class PointPlanner:
    """The planner of one device: its declared points, limits and line, and
    what the device taught it.

    ``items``: every point the device may be asked for (a block's channels
    an item each). ``offline_retry``: seconds after which a point the device
    refused alone is asked for again. Plans are cached until something is
    learnt or :meth:`forget` is called.
    """

    def __init__(self, items: Sequence[Item], limits: Limits, line: Line, *,
                 offline_retry: float = 30.0,
                 clock: Callable[[], float] = time.monotonic,
                 ties: Sequence[tuple[int, int]] = (),
                 point_of: Sequence[int] = ()) -> None:
        self.items = tuple(items)
        #: per item, the index of the point it is of (a block's channels
        #: share one); empty: unknown
        self.point_of = tuple(point_of)
        #: the device has or lacks a point whole (:func:`~pymb.maps.planner.on_refusal`
        #: reads a refused request point by point, and a point refused alone
        #: is unsupported whole, not probed channel by channel)
        self.whole_points = False
        #: pairs of items read in one request where the rules allow (a value
        #: and its scale factor)
        self.ties = tuple(ties)
        self.limits = limits
        self.line = line
        self.offline_retry = offline_retry
        self.clock = clock  #: the time :attr:`retry_at` and unsupported points' retries are on
        #: changes of what the device taught (bridges refused, points
        #: unsupported or due again, forgotten): a plan made at one version
        #: is the plan while the version is the same and :attr:`retry_at`
        #: has not come
        self.version = 0
        #: when the first unsupported point is due to be asked again (inf: none)
        self.retry_at = math.inf
        self._refused: dict[str, list[tuple[int, int]]] = {}
        self._unsupported: dict[int, float] = {}  # item -> when to ask again
        self._known: dict[str, Known] | None = None
        self._plans: dict[tuple[int, ...], ReadPlan] = {}
        # the last plan and the very tuple it was asked for: a poll that asks
        # with the same tuple again finds it without hashing it
        self._last: tuple[tuple[int, ...], ReadPlan] | None = None

    def _knowledge(self) -> dict[str, Known]:
        if self._known is None:
            declared: dict[str, list[tuple[int, int]]] = {}
            for k, it in enumerate(self.items):
                if k not in self._unsupported:
                    declared.setdefault(it.table, []).append((it.address, it.end))
            refused = {t: list(r) for t, r in self._refused.items()}
            for k in self._unsupported:
                it = self.items[k]
                refused.setdefault(it.table, []).append((it.address, it.end))
            tables = set(declared) | set(refused) | set(self.limits.readable)
            self._known = {
                t: Known(declared.get(t, ()),
                         [(a, b + 1) for a, b in self.limits.readable.get(t, ())],
                         refused.get(t, ()))
                for t in tables
            }
        return self._known

    def _changed(self) -> None:
        self._known = None
        self._plans.clear()
        self._last = None
        self.version += 1
        self.retry_at = min(self._unsupported.values(), default=math.inf)

    @property
    def unsupported(self) -> frozenset[int]:
        """Items the device refused alone (not asked for until their retry)."""
        return frozenset(self._unsupported)

    def plan(self, wanted: Sequence[int] | None = None) -> ReadPlan:
        """The plan for the ``wanted`` items (indices; all by default), without
        the unsupported ones whose retry time has not come."""
        if self._unsupported:
            now = self.clock()
            due = [k for k, t in self._unsupported.items() if t <= now]
            for k in due:
                del self._unsupported[k]
            if due:
                self._changed()
        last = self._last
        if last is not None and wanted is last[0]:
            return last[1]
        key = tuple(range(len(self.items))) if wanted is None else tuple(wanted)
        plan = self._plans.get(key)
        if plan is None:
            chosen = [k for k in key if k not in self._unsupported]
            plan = plan_points(self.items, self.line, self.limits, wanted=chosen,
                               known=self._knowledge(), ties=self.ties)
            if len(self._plans) >= _CACHED:
                self._plans.clear()  # many different selections: keep memory bounded
            self._plans[key] = plan
        if isinstance(wanted, tuple):
            self._last = (wanted, plan)
        return plan

    def replan(self, request: Request) -> ReadPlan:
        """A plan for the points of ``request`` alone, with what is known now
        (after :meth:`refuse_bridge`): the same poll's second try."""
        return plan_points(self.items, self.line, self.limits, wanted=request.items,
                           known=self._knowledge(), ties=self.ties)

    def refuse_bridge(self, request: Request) -> list[tuple[int, int]]:
        """The device refused ``request`` (exception 02/03), which read
        registers no wanted point needs: never bridge those again. Returns
        the gaps, half-open."""
        gaps = []
        ends = {}
        for ext in request.extents:
            a = min(self.items[k].address for k in ext)
            ends[a] = max(self.items[k].end for k in ext)
        prev = None
        for a in sorted(ends):
            if prev is not None and a > prev:
                gaps.append((prev, a))
            prev = ends[a] if prev is None else max(prev, ends[a])
        if gaps:
            self._refused.setdefault(request.table, []).extend(gaps)
            self._changed()
        return gaps

    def mark_unsupported(self, indices: Iterable[int]) -> None:
        """The device refused these points alone: leave them out of plans
        for ``offline_retry`` seconds."""
        retry = self.clock() + self.offline_retry
        for k in indices:
            self._unsupported[k] = retry
        self._changed()

    def forget(self) -> None:
        """Forget refused bridges and points (a new connection may be a new device)."""
        if self._refused or self._unsupported:
            self._refused.clear()
            self._unsupported.clear()
            self._changed()


@dataclass(frozen=True)
class MapItems:
    """A map's readable points as planner items: ``points`` (file order, no
    write-only ones), and for each the index of its first item (a block
    has one item per channel, in channel order)."""

    points: tuple[Point, ...]
    first: tuple[int, ...]
    items: tuple[Item, ...]

    @classmethod
    def of(cls, m: Points) -> MapItems:
        """The items of map ``m``."""
        points = tuple(p for p in m.points.values() if p.access != "w")
        items: list[Item] = []
        first: list[int] = []
        for p in points:
            first.append(len(items))
            if p.block:
                items.extend(Item(f"{p.name}[{c}]", p.table, p.address_of(c), p.count)
                             for c in range(1, p.channels + 1))
            else:
                items.append(Item(p.name, p.table, p.address, p.count))
        return cls(points, tuple(first), tuple(items))

    def wanted(self, indices: Iterable[int]) -> list[int]:
        """The items of the points at ``indices`` (into :attr:`points`)."""
        out: list[int] = []
        for i in indices:
            out.extend(range(self.first[i], self.first[i] + self.points[i].channels))
        return out

    def group(self, group: str | None) -> list[int]:
        """Indices of the points of ``group`` (every readable point for None),
        then those of the scale factors its ``scale_from`` points need."""
        chosen = [i for i, p in enumerate(self.points) if group is None or p.group == group]
        index = {p.name: i for i, p in enumerate(self.points)}
        for i in list(chosen):
            sf = self.points[i].scale_from
            if sf is not None and index[sf] not in chosen:
                chosen.append(index[sf])
        return chosen

    def ties(self) -> list[tuple[int, int]]:
        """(item, its scale factor's item) for each ``scale_from`` point (each
        channel of a block): the pairs the planner keeps in one request."""
        index = {p.name: i for i, p in enumerate(self.points)}
        out: list[tuple[int, int]] = []
        for i, p in enumerate(self.points):
            if p.scale_from is not None:
                sf = self.first[index[p.scale_from]]
                out.extend((k, sf) for k in range(self.first[i], self.first[i] + p.channels))
        return out


def map_planner(m: Points, line: Line | None = None, *, clock: Callable[[], float] = time.monotonic
                ) -> tuple[PointPlanner, MapItems]:
    """The planner of a device map ``m``: its limits, its ``turnaround`` and
    ``inter_request_gap`` on ``line`` (default 9600 bit/s 8N1)."""
    timing = m.timing
    base = line or Line()
    line = Line(base.baudrate, base.bits_per_char, timing.turnaround, timing.inter_request_gap)
    mi = MapItems.of(m)
    point_of = [i for i, p in enumerate(mi.points) for _ in range(p.channels)]
    return PointPlanner(mi.items, m.limits, line, offline_retry=timing.offline_retry,
                        clock=clock, ties=mi.ties(), point_of=point_of), mi
