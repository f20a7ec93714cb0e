"""The point planner: never splits a point, keeps every limit, bridges only
what is known to exist, and is the cheapest plan (against brute force)."""

from __future__ import annotations

import itertools
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pymb.errors import InvalidArgument
from pymb.maps.device_plan import PointPlanner
from pymb.maps.planner import (
    Item,
    Known,
    Limits,
    Line,
    Refusal,
    on_refusal,
    plan_points,
    replans,
)
from pymb.wire import read_bits_time, read_time


@st.composite
def point_sets(draw: st.DrawFn) -> list[Item]:
    """Points of one table at increasing addresses, some overlapping (views)."""
    n = draw(st.integers(1, 9))
    items = []
    a = draw(st.integers(0, 20))
    for i in range(n):
        w = draw(st.sampled_from([1, 1, 2, 2, 4, 8]))
        items.append(Item(f"p{i}", "holding", a, w))
        a += draw(st.sampled_from([-1, 0, w, w, w + 1, w + 2, w + 5, w + 30]))
        a = max(a, 0)
    return items


def covered(requests: object) -> list[tuple[int, int]]:
    return [(r.address, r.address + r.count) for r in requests]  # type: ignore[attr-defined]


def extents(items: list[Item]) -> list[list[int]]:
    """Points merged where they overlap: [start, end) each."""
    ext: list[list[int]] = []
    for it in sorted(items, key=lambda i: i.address):
        if ext and it.address < ext[-1][1]:
            ext[-1][1] = max(ext[-1][1], it.end)
        else:
            ext.append([it.address, it.end])
    return ext


def brute_force(items: list[Item], limits: Limits, line: Line, known: Known) -> float:
    """The least cost over every way of cutting the extents into requests."""
    ext = extents(items)
    best = float("inf")
    for cuts in itertools.product([False, True], repeat=len(ext) - 1):
        cost, start, ok = 0.0, ext[0][0], True
        for k in range(len(ext)):
            last = k == len(ext) - 1 or cuts[k]
            if not last and not (ext[k][1] == ext[k + 1][0] or known.bridgeable(
                    ext[k][1], ext[k + 1][0], limits.max_gap)):
                ok = False
                break
            if last:
                n = ext[k][1] - start
                if n > limits.max_registers:
                    ok = False
                    break
                cost += line.cost("holding", n)
                if k + 1 < len(ext):
                    start = ext[k + 1][0]
        if ok:
            best = min(best, cost)
    return best


@settings(max_examples=300, deadline=None)
@given(items=point_sets(), max_registers=st.sampled_from([8, 10, 16, 125]),
       max_gap=st.sampled_from([0, 1, 3, 10]), baud=st.sampled_from([1200, 9600, 115200]),
       turnaround=st.sampled_from([0.0, 0.004, 0.03]), gap=st.sampled_from([0.0, 0.01]),
       declared_extra=st.lists(st.tuples(st.integers(0, 120), st.integers(1, 6)), max_size=4),
       readable=st.sampled_from([None, (0, 60), (10, 200)]))
def test_plans_keep_the_rules_and_are_optimal(items: list[Item], max_registers: int,
                                              max_gap: int, baud: int, turnaround: float,
                                              gap: float,
                                              declared_extra: list[tuple[int, int]],
                                              readable: tuple[int, int] | None) -> None:
    if any(b - a > max_registers for a, b in extents(items)):
        with pytest.raises(InvalidArgument, match="never splits a point"):
            plan_points(items, Line(), Limits(max_registers=max_registers))
        return
    limits = Limits(max_registers=max_registers, max_gap=max_gap,
                    readable={"holding": [readable]} if readable else {})
    line = Line(baud, 10, turnaround, gap)
    declared = [(it.address, it.end) for it in items] + [(a, a + w) for a, w in declared_extra]
    known = Known(declared, [(readable[0], readable[1] + 1)] if readable else [])
    plan = plan_points(items, line, limits, known={"holding": known})
    spans = covered(plan.requests)
    for a, b in spans:
        assert 1 <= b - a <= max_registers
    # every point is inside exactly one request, whole
    for k, it in enumerate(items):
        inside = [(a, b) for a, b in spans if a <= it.address and it.end <= b]
        assert len(inside) == 1, (it, spans)
        assert sum(k in r.items for r in plan.requests) == 1
    # requests do not overlap; every register read is wanted or known to exist
    wanted = {x for it in items for x in range(it.address, it.end)}
    for (_, b), (c, _) in itertools.pairwise(sorted(spans)):
        assert b <= c
    for r in plan.requests:
        regs = list(range(r.address, r.address + r.count))
        holes = [x for x in regs if x not in wanted]
        assert r.bridged == len(holes)
        runs: list[list[int]] = []
        for x in holes:
            if runs and runs[-1][-1] + 1 == x:
                runs[-1].append(x)
            else:
                runs.append([x])
        for run in runs:
            assert known.bridgeable(run[0], run[-1] + 1, max_gap)
    # the price is the wire model's, and it is the least there is
    assert plan.predicted_s == pytest.approx(sum(line.cost("holding", b - a) for a, b in spans))
    assert plan.predicted_s == pytest.approx(brute_force(items, limits, line, known))
    assert plan.predicted_s <= plan.naive_s + 1e-12


def test_a_32_bit_value_is_never_torn_at_the_limit() -> None:
    # 62 f32 values then one more: 128 registers. An address planner reads
    # (0, 125), (125, 3) and tears the value at 124..125.
    items = [Item(f"v{i}", "input", 2 * i, 2) for i in range(64)]
    plan = plan_points(items, Line(9600))
    assert [r.count for r in plan.requests] == [124, 4]
    assert all(r.address % 2 == 0 for r in plan.requests)


def test_undeclared_registers_are_bridged_only_within_max_gap() -> None:
    items = [Item("a", "holding", 0, 2), Item("b", "holding", 5, 2), Item("c", "holding", 20, 1)]
    line = Line(9600, turnaround=0.05)  # a slow device: merging pays
    assert plan_points(items, line).spans == ((0, 2), (5, 2), (20, 1))
    assert plan_points(items, line, Limits(max_gap=3)).spans == ((0, 7), (20, 1))
    assert plan_points(items, line, Limits(max_gap=13)).spans == ((0, 21),)


def test_readable_ranges_bound_the_bridges() -> None:
    items = [Item("a", "input", 0, 2), Item("b", "input", 5, 2), Item("c", "input", 20, 1)]
    line = Line(9600, turnaround=0.05)
    limits = Limits(readable={"input": [(0, 10)]})
    known = {"input": Known([(0, 2), (5, 7), (20, 21)], [(0, 11)])}
    assert plan_points(items, line, limits, known=known).spans == ((0, 7), (20, 1))
    # max_gap still applies inside readable
    limits = Limits(max_gap=2, readable={"input": [(0, 10)]})
    assert plan_points(items, line, limits, known=known).spans == ((0, 2), (5, 2), (20, 1))
    # and max_gap = 0 said outright reads only declared registers, readable or not
    # (device-map.md section 3); only an unset max_gap means any gap inside readable
    limits = Limits(max_gap=0, readable={"input": [(0, 10)]})
    assert plan_points(items, line, limits, known=known).spans == ((0, 2), (5, 2), (20, 1))


def test_max_gap_has_one_range_at_load_and_plan() -> None:
    from pymb.errors import InvalidArgument
    from pymb.maps import loads
    from pymb.maps.planner import MAX_GAP

    head = ('schema = "pymb.map/1"\n[device]\nid = "x"\n[device.limits]\nmax_gap = {}\n'
            '[[point]]\nname = "a"\naddress = 0\ntable = "holding"\ntype = "u16"\n')
    assert loads(head.format(MAX_GAP)).limits.max_gap == MAX_GAP
    Limits(max_gap=MAX_GAP)
    for bad in (MAX_GAP + 1, -1):
        with pytest.raises(ValueError, match=f"max_gap must be .*0..{MAX_GAP}"):
            loads(head.format(bad))
        with pytest.raises(InvalidArgument, match=f"max_gap must be 0..{MAX_GAP}"):
            Limits(max_gap=bad)
    unset = head.replace("max_gap = {}\n", "")
    assert loads(unset).limits.max_gap is None


def test_other_declared_points_may_be_bridged() -> None:
    wanted = [Item("a", "holding", 0, 2), Item("c", "holding", 10, 2)]
    line = Line(9600, turnaround=0.05)
    other_group = Known([(0, 2), (2, 10), (10, 12)])
    assert plan_points(wanted, line, known={"holding": other_group}).spans == ((0, 12),)


def test_single_point_requests_and_views_read_once() -> None:
    items = [Item("status", "holding", 3, 1), Item("alarm", "holding", 3, 1),
             Item("energy", "holding", 2, 2), Item("x", "holding", 4, 1)]
    plan = plan_points(items, Line(9600), Limits(single_point_requests=True))
    # the status word, its bit view and the u32 under it overlap: one extent
    assert plan.spans == ((2, 2), (4, 1))
    assert plan.requests[0].extents == ((2, 0, 1),)


def test_bits_are_planned_in_bits() -> None:
    items = [Item(f"c{i}", "coil", 16 * i, 1) for i in range(4)]
    line = Line(9600)
    plan = plan_points(items, line, known={"coil": Known([(0, 64)])})
    assert plan.spans == ((0, 49),)
    assert plan.predicted_s == pytest.approx(read_bits_time(49, 9600))
    small = plan_points(items, line, Limits(max_bits=20), known={"coil": Known([(0, 64)])})
    assert max(c for _, c in small.spans) <= 20


def test_inter_request_gap_and_turnaround_price_requests() -> None:
    items = [Item("a", "input", 0, 1), Item("b", "input", 40, 1)]
    known = {"input": Known([(0, 41)])}
    fast = plan_points(items, Line(19200), known=known)
    assert fast.spans == ((0, 1), (40, 1))
    gappy = plan_points(items, Line(19200, inter_request_gap=0.05), known=known)
    assert gappy.spans == ((0, 41),)
    assert gappy.predicted_s == pytest.approx(read_time(41, 19200, gap=0.05))
    assert "inter-request gap 50 ms" in gappy.explain()


def test_planner_remembers_refused_bridges_and_unsupported_points() -> None:
    now = [100.0]
    items = [Item("a", "holding", 0, 2), Item("b", "holding", 4, 2), Item("c", "holding", 8, 1)]
    planner = PointPlanner(items, Limits(max_gap=2), Line(9600, turnaround=0.05),
                           offline_retry=30.0, clock=lambda: now[0])
    first = planner.plan()
    assert first.spans == ((0, 9),)
    assert planner.refuse_bridge(first.requests[0]) == [(2, 4), (6, 8)]
    assert planner.replan(first.requests[0]).spans == ((0, 2), (4, 2), (8, 1))
    assert planner.plan().spans == ((0, 2), (4, 2), (8, 1))
    planner.mark_unsupported([1])
    assert planner.plan().spans == ((0, 2), (8, 1))
    assert planner.unsupported == {1}
    now[0] += 29.0
    assert planner.plan().spans == ((0, 2), (8, 1))
    now[0] += 1.0
    assert planner.plan().spans == ((0, 2), (4, 2), (8, 1))
    planner.forget()
    assert planner.plan().spans == ((0, 9),)


def test_the_planner_s_version_counts_what_it_learns_and_retry_at_the_first_retry() -> None:
    now = [100.0]
    items = [Item("a", "holding", 0, 2), Item("b", "holding", 4, 2), Item("c", "holding", 8, 1)]
    planner = PointPlanner(items, Limits(max_gap=2), Line(9600), offline_retry=30.0,
                           clock=lambda: now[0])
    v = planner.version
    first = planner.plan()
    assert planner.plan() is first
    assert planner.version == v  # planning teaches nothing
    assert planner.retry_at == math.inf
    planner.refuse_bridge(first.requests[0])
    assert planner.version == v + 1
    planner.mark_unsupported([1])
    assert (planner.version, planner.retry_at) == (v + 2, 130.0)
    now[0] += 10.0
    planner.mark_unsupported([2])
    assert (planner.version, planner.retry_at) == (v + 3, 130.0)  # the first one due
    now[0] = 130.0
    planner.plan()  # item 1 is due again: asked for, and item 2's retry is next
    assert (planner.version, planner.retry_at) == (v + 4, 140.0)
    assert planner.unsupported == {2}
    planner.forget()
    assert (planner.version, planner.retry_at) == (v + 5, math.inf)
    planner.forget()  # nothing to forget: nothing changes
    assert planner.version == v + 5


def test_a_point_wider_than_a_request_is_a_clear_error() -> None:
    with pytest.raises(InvalidArgument, match=r"name .* take 130 registers"):
        plan_points([Item("name", "holding", 0, 130)], Line())
    with pytest.raises(InvalidArgument, match=r"max_registers must be 1\.\.125"):
        Limits(max_registers=126)


def test_a_maps_plan_is_the_planners() -> None:
    import reference as ref

    from pymb import maps

    hub = maps.builtin("hub")
    plan = hub.plan(group="sweep")
    assert [(r.table, r.address, r.count) for r in plan] == [
        ("holding", a, n) for a, n in ref.hub_sweep_spans(0, 100)]
    assert len(plan) == 6
    # 50 channels at 9600 bit/s: the 50 registers between the blocks are
    # readable, but a second request is cheaper than reading them
    assert hub.configure(channels=50).plan("sweep").spans == tuple(
        (31 + 100 * b, 50) for b in range(7))
    with pytest.raises(maps.MapError, match="no group 'sweeep'; did you mean 'sweep'"):
        hub.plan("sweeep")


def test_the_one_re_plan_policy_after_a_refused_read() -> None:
    """Exception 02/03 (with ``split_on_exception``): a bridged read is planned
    again without its bridge, a read of several extents is read extent by
    extent, a single extent's points are marked unsupported; another code,
    or the option off, fails the poll (None). Every poller calls this."""
    items = [Item("a", "holding", 0, 2), Item("b", "holding", 4, 2)]
    p = PointPlanner(items, Limits(max_gap=5), Line())
    (bridged,) = p.plan().requests
    assert (bridged.address, bridged.count, bridged.bridged) == (0, 6, 2)
    assert on_refusal(p, bridged, 4) is None
    assert not replans(p.limits, 1)
    assert replans(p.limits, 2)
    assert replans(p.limits, 3)
    got = on_refusal(p, bridged, 2)
    assert got is not None
    assert got.unsupported == ()
    assert covered(got.requests) == [(0, 2), (4, 6)]
    assert covered(p.plan().requests) == [(0, 2), (4, 6)]  # never bridged again
    alone = got.requests[0]
    got = on_refusal(p, alone, 3)
    assert got == Refusal((), (0,))
    assert covered(p.plan().requests) == [(4, 6)]  # left out until offline_retry

    side = PointPlanner([Item("a", "input", 0, 2), Item("b", "input", 2, 2)], Limits(), Line())
    (both,) = side.plan().requests
    assert both.extents == ((0,), (1,))
    assert not both.bridged
    got = on_refusal(side, both, 2)
    assert got is not None
    assert got.unsupported == ()
    assert covered(got.requests) == [(0, 2), (2, 4)]
    assert [r.items for r in got.requests] == [(0,), (1,)]

    off = PointPlanner(items, Limits(max_gap=5, split_on_exception=False), Line())
    assert on_refusal(off, off.plan().requests[0], 2) is None
    assert covered(off.plan().requests) == [(0, 6)]  # nothing learnt
