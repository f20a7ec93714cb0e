"""Two planner rules of the map format: per-range limits (``[device.limits]
ranges``: a request touching those addresses reads at most so many
registers) and tied pairs (a ``scale_from`` point and its scale factor, read
in one request wherever the rules allow). Checked against a brute force over
every cut, and end to end against a scripted responder that refuses (03) a
longer read in its range."""

from __future__ import annotations

import itertools
import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from peers import TcpPeer

import pymb
from pymb import maps
from pymb.devices.mapdevice import MapDevice
from pymb.maps.planner import Item, Known, Limits, Line, plan_points


@st.composite
def items_ranges(draw: st.DrawFn) -> tuple[list[Item], list[tuple[str, int, int, int]]]:
    n = draw(st.integers(1, 8))
    items, a = [], draw(st.integers(0, 10))
    for i in range(n):
        w = draw(st.sampled_from([1, 1, 2, 4]))
        items.append(Item(f"p{i}", "holding", a, w))
        a += w + draw(st.sampled_from([0, 0, 1, 3]))
    ranges = []
    for _ in range(draw(st.integers(0, 2))):
        first = draw(st.integers(0, a))
        ranges.append(("holding", first, first + draw(st.integers(0, 12)),
                       draw(st.sampled_from([1, 2, 4, 6]))))
    return items, ranges


def extents(items: list[Item]) -> list[tuple[int, int]]:
    return [(it.address, it.end) for it in sorted(items, key=lambda i: i.address)]


def cap(a: int, b: int, most: int, ranges: list[tuple[str, int, int, int]]) -> int:
    """The most registers a request [a, b) may read."""
    return min([most] + [m for _, f, last, m in ranges if f <= b - 1 and a <= last])


def brute(items: list[Item], limits: Limits, line: Line, known: Known,
          ties: list[tuple[int, int]]) -> tuple[tuple[int, float], int]:
    """Over every cut: the least (cuts between tied pairs, counted once for
    each pair a cut separates; then cost), the planner's order; and the
    fewest pairs separated."""
    ext = extents(items)
    order = sorted(range(len(items)), key=lambda k: items[k].address)
    best = (1 << 30, float("inf"))
    fewest = 1 << 30
    for cuts in itertools.product([False, True], repeat=len(ext) - 1):
        cost, start, ok, req, which = 0.0, ext[0][0], True, 0, {}
        for k in range(len(ext)):
            which[order[k]] = req
            last = k == len(ext) - 1 or cuts[k]
            if not last and not (ext[k][1] == ext[k + 1][0] or known.bridgeable(
                    ext[k][1], ext[k + 1][0], limits.max_gap)):
                ok = False
                break
            if last:
                n = ext[k][1] - start
                if n > cap(start, ext[k][1], limits.max_registers, list(limits.ranges)):
                    ok = False
                    break
                cost += line.cost("holding", n)
                req += 1
                if k + 1 < len(ext):
                    start = ext[k + 1][0]
        if ok:
            crossings = sum(which[b] - which[a] if which[a] < which[b] else which[a] - which[b]
                            for a, b in ties)
            best = min(best, (crossings, cost))
            fewest = min(fewest, sum(which[a] != which[b] for a, b in ties))
    return best, fewest


@settings(max_examples=300, deadline=None)
@given(case=items_ranges(), baud=st.sampled_from([1200, 9600, 115200]),
       max_registers=st.sampled_from([6, 125]), data=st.data())
def test_plans_keep_range_limits_and_ties_and_are_optimal(
        case: tuple[list[Item], list[tuple[str, int, int, int]]], baud: int,
        max_registers: int, data: st.DataObject) -> None:
    items, ranges = case
    if any(it.width > cap(it.address, it.end, max_registers, ranges) for it in items):
        return  # the loader refuses a point no request may read
    n = len(items)
    ties = data.draw(st.lists(st.tuples(st.integers(0, n - 1), st.integers(0, n - 1)),
                              max_size=2))
    limits = Limits(max_registers=max_registers, max_gap=3, ranges=ranges)
    line = Line(baud)
    known = Known([(it.address, it.end) for it in items])
    plan = plan_points(items, line, limits, known={"holding": known}, ties=ties)
    where = {}
    for i, r in enumerate(plan.requests):
        assert r.count <= cap(r.address, r.address + r.count, max_registers, ranges), r
        for k in r.items:
            where[k] = i
    assert sorted(where) == list(range(n))
    broken = sum(where[a] != where[b] for a, b in ties)
    crossings = sum(abs(where[a] - where[b]) for a, b in ties)
    best, fewest = brute(items, limits, line, known, ties)
    assert (crossings, plan.predicted_s) == pytest.approx(best)
    if fewest == 0:  # where some plan keeps every pair together, the plan does
        assert broken == 0
    assert plan.predicted_s <= plan.naive_s + 1e-12 or ties


EM = '''schema = "pymb.map/1"
[device]
id = "em"
table = "input"
[device.limits]
ranges = [{ first = 0x0100, last = 0x0103, max_registers = 1 }]
[[point]]
name = "before"
address = 0x00FE
type = "u32"
[[block]]
name = "one_at_a_time"
first = 0x0100
count = 4
type = "u16"
[[point]]
name = "after"
address = 0x0104
type = "u32"
'''


def test_a_device_that_reads_a_range_one_word_at_a_time() -> None:
    m = maps.loads(EM)
    peer = TcpPeer()
    words = peer.memory.inputs
    words[0xFE:0x106] = list(range(0x1000, 0x1008))

    def hook(slave: int, pdu: bytes, normal: bytes | None) -> list[tuple[float, bytes]] | None:
        address, count = struct.unpack(">HH", pdu[1:5])
        if pdu[0] == 4 and address <= 0x103 and address + count > 0x100 and count > 1:
            return [(0.0, peer.frame(slave, bytes((0x84, 3))))]
        return None

    peer.hook = hook
    with peer, pymb.TcpClient("127.0.0.1", peer.port, timeout=2.0) as client:
        dev = MapDevice(client, m, 1)
        assert dev.read() == {"before": 0x10001001, "one_at_a_time": [0x1002, 0x1003, 0x1004,
                                                                      0x1005],
                              "after": 0x10061007}
        reads = [struct.unpack(">HH", pdu[1:5]) for _, pdu in peer.requests if pdu[0] == 4]
        assert reads == [(0xFE, 2), (0x100, 1), (0x101, 1), (0x102, 1), (0x103, 1), (0x104, 2)]


@pytest.mark.parametrize(("limits", "message"), [
    ('ranges = [{ first = 0x0100, last = 0x0103, max_registers = 1, size = 2 }]',
     "unknown key 'size'"),
    ('ranges = [{ first = 0x0104, last = 0x0100, max_registers = 1 }]', "first <= last"),
    ('ranges = [{ first = 0x0100, last = 0x0103, max_bits = 1 }]', "gives max_registers"),
    ('ranges = [{ first = 0x0105, last = 0x0106, max_registers = 1 }]',
     "'after': key 'ranges': the point is 2 registers .* it could never be read"),
])
def test_range_limits_that_cannot_be_are_refused(limits: str, message: str) -> None:
    text = EM.replace('ranges = [{ first = 0x0100, last = 0x0103, max_registers = 1 }]', limits)
    with pytest.raises(maps.MapError, match=message) as e:
        maps.loads(text, source="em.toml")
    assert str(e.value).startswith("em.toml: ")
