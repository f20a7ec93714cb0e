"""``client.run_read_plan(plan, start, on)``: a prepared plan run only on the
connection it is from (docs/library.md, the device seam), against a scripted
peer on a real pseudo-terminal."""

from __future__ import annotations

from array import array
from collections.abc import Iterator

import pytest
from conftest import TIMEOUT
from peers import PtyPeer

import pymb
from pymb._native.link import RegisterPlan


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
