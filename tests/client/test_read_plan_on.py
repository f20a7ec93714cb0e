"""``client.run_read_plan(plan, start, on)``: a prepared plan run only on the
connection it is from (docs/library.md, the device seam), and the same made
ready (``pymb.client.base.read_plan_call``), against scripted peers on real
pseudo-terminals."""

from __future__ import annotations

from array import array
from collections.abc import Iterator

import pytest
from conftest import TIMEOUT
from map_peers import RefusingPtyPeer
from peers import PtyPeer

import pymb
from pymb._native.link import RegisterPlan
from pymb.client.base import line_of, read_plan_call
from pymb.client.core import line_lock


@pytest.fixture
def peer() -> Iterator[PtyPeer]:
    with PtyPeer() as p:
        yield p


def test_a_plan_runs_only_on_its_connection(peer: PtyPeer) -> None:
    regs = array("H", bytes(8))
    plan = RegisterPlan([(0x04, 40, 0, 4, 0)], regs)
    c = pymb.RtuClient(peer.port, timeout=TIMEOUT)
    c.connect()
    try:
        on = c.fresh_connections
        assert on == c.connections - c.resends == 1
        assert c.run_read_plan(plan, 0, on) is True  # this connection: sent and read
        assert list(regs[:4]) == [0, 1, 2, 3]
        assert len(peer.requests) == 1
        assert c.run_read_plan(plan, 0, on + 1) is False  # another: nothing sent
        c.close()
        assert c.run_read_plan(plan, 0, on) is False  # closed: nothing sent
        assert len(peer.requests) == 1
        c.connect()  # a new connection, which may be to another device
        assert c.fresh_connections == on + 1
        assert c.run_read_plan(plan, 0, on) is False
        assert c.run_read_plan(plan, 0, on + 1) is True
        assert len(peer.requests) == 2
    finally:
        c.close()


def test_a_plan_made_ready_runs_as_run_read_plan_held(peer: PtyPeer) -> None:
    # read_plan_call(client, plan)(on) is run_read_plan_held(client, plan, 0, on):
    # its steady case (the line it last ran on, still open) is a C call of one
    # argument; a line opened again is taken up again.
    regs = array("H", bytes(8))
    plan = RegisterPlan([(0x04, 40, 0, 4, 0)], regs)
    c = pymb.RtuClient(peer.port, timeout=TIMEOUT)
    c.connect()
    try:
        run = read_plan_call(c, plan)
        on = c.fresh_connections
        with line_lock(c):
            assert run(on) is True
            assert run(on) is True
            assert run(on + 1) is False  # another connection: nothing sent
        assert list(regs[:4]) == [0, 1, 2, 3]
        assert len(peer.requests) == 2
        c.close()
        assert run(on) is False  # closed: nothing sent
        c.connect()
        regs[:4] = array("H", bytes(8))
        assert run(on + 1) is True
        assert list(regs[:4]) == [0, 1, 2, 3]
        assert len(peer.requests) == 3
    finally:
        c.close()


def test_a_plan_made_ready_raises_what_the_device_answers() -> None:
    regs = array("H", bytes(8))
    plan = RegisterPlan([(0x03, 1, 5, 2, 0)], regs)
    with RefusingPtyPeer({"holding": {5}}) as peer, \
            pymb.RtuClient(peer.port, timeout=TIMEOUT) as c:
        run = read_plan_call(c, plan)
        on = c.fresh_connections
        for _ in range(2):  # taken up through run_read_plan_held, then its own call
            with pytest.raises(pymb.IllegalDataAddress):
                run(on)
            assert plan.failed == 0
        assert [r.refused for r in peer.log] == [2, 2]
        assert c.connected


def test_an_armed_plan_is_taken_up_again_after_whatever_changes_the_line(
        peer: PtyPeer) -> None:
    # A run that got its reply arms the plan: its next runs are its C call
    # alone. A request with the line's own reply timeout, a new timeout, or a
    # new connection disarms it; the next run takes it up again, and reads.
    regs = array("H", bytes(8))
    plan = RegisterPlan([(0x04, 40, 0, 4, 0)], regs, timeout=TIMEOUT / 2)
    c = pymb.RtuClient(peer.port, timeout=TIMEOUT)
    c.connect()
    try:
        line = line_of(c)
        run = read_plan_call(c, plan)
        on = c.fresh_connections
        with line_lock(c):
            assert run(on) is True
            assert plan.armed == line.era
            assert run(on) is True
            assert run(on + 1) is False  # armed, but another connection: nothing sent
        assert len(peer.requests) == 2
        for change in (lambda: c.read_input_registers(0, 2, slave=40),
                       lambda: c.set_timeout(TIMEOUT)):
            change()
            assert plan.armed != line.era
            regs[:4] = array("H", bytes(8))
            with line_lock(c):
                assert run(on) is True
            assert list(regs[:4]) == [0, 1, 2, 3]
            assert plan.armed == line.era
        c.close()
        c.connect()
        assert plan.armed != line.era
        assert run(on) is False  # its connection is gone: nothing sent
        assert run(on + 1) is True
        assert plan.armed == line.era
        assert len(peer.requests) == 6
    finally:
        c.close()


def test_plans_of_one_reply_timeout_stay_armed_side_by_side(peer: PtyPeer) -> None:
    a, b = array("H", bytes(8)), array("H", bytes(8))
    pa = RegisterPlan([(0x04, 40, 0, 2, 0)], a)  # the line's own timeout, both
    pb = RegisterPlan([(0x04, 40, 2, 2, 0)], b)
    with pymb.RtuClient(peer.port, timeout=TIMEOUT) as c:
        line = line_of(c)
        ra, rb = read_plan_call(c, pa), read_plan_call(c, pb)
        on = c.fresh_connections
        for _ in range(3):
            assert ra(on) is True
            assert rb(on) is True
            assert pa.armed == pb.armed == line.era
        assert (list(a[:2]), list(b[:2])) == ([0, 1], [2, 3])
        assert len(peer.requests) == 6


def test_plans_of_one_explicit_reply_timeout_stay_armed_side_by_side(peer: PtyPeer) -> None:
    # Two devices of one map (its response_timeout) on one line: their plans
    # hold the same timeout, so neither disarms the other.
    a, b = array("H", bytes(8)), array("H", bytes(8))
    pa = RegisterPlan([(0x04, 40, 0, 2, 0)], a, timeout=TIMEOUT / 2)
    pb = RegisterPlan([(0x04, 40, 2, 2, 0)], b, timeout=TIMEOUT / 2)
    with pymb.RtuClient(peer.port, timeout=TIMEOUT) as c:
        line = line_of(c)
        ra, rb = read_plan_call(c, pa), read_plan_call(c, pb)
        on = c.fresh_connections
        for _ in range(3):
            with line_lock(c):
                assert ra(on) is True
                assert rb(on) is True
            assert pa.armed == pb.armed == line.era
        assert (list(a[:2]), list(b[:2])) == ([0, 1], [2, 3])
        assert len(peer.requests) == 6
