"""Write commands to a device polled by the one Modbus TCP loop go over its
poll connection, between two polls: a scripted Modbus TCP device that serves
one connection at a time (as many gateways and single-master devices do) and
logs every request sees one connection, every poll whole, each write and its
read back between two polls. ``pymb log`` in its own process, mosquitto,
paho."""

from __future__ import annotations

import itertools
import socket
from collections.abc import Iterator
from pathlib import Path

import pytest
from mqtt_broker import Fleet, fleet, mosquitto  # noqa: F401 (fixtures)
from write_mqtt import Commander, clean_polls_after_the_writes, start, stop, writes_sent
from write_peers import WRITE_MAP, FreezingTcpPeer

pytest.importorskip("paho.mqtt.client")


class CountingPeer(FreezingTcpPeer):
    """Counts the connections it accepted (one at a time)."""

    connections = 0

    def _serve(self, conn: socket.socket) -> None:
        self.connections += 1
        super()._serve(conn)


@pytest.fixture
def peer() -> Iterator[CountingPeer]:
    with CountingPeer() as p:
        p.memory.holding[10] = 5000
        p.memory.holding[12] = 0
        yield p


def test_writes_share_the_poll_connection_and_never_tear_a_poll(
        fleet: Fleet, peer: CountingPeer, tmp_path: Path) -> None:  # noqa: F811
    map_file = tmp_path / "wdev.toml"
    map_file.write_text(WRITE_MAP.format(device="", limits="", budget=""))
    broker = fleet.broker()
    proc = start(fleet, broker, None, map_file, tmp_path / "log.sqlite",
                 "--tcp", f"127.0.0.1:{peer.port}")
    cmd = Commander(fleet, broker)
    try:
        assert cmd.send({"id": "t-0", "values": {"setpoint_hz": 49}})["ok"]
        for i in range(1, 21):
            values = {"setpoint_hz": 45 + i % 10} if i % 2 else {
                "mode": "run" if i % 4 else "stop", "relay_5": bool(i % 8)}
            r = cmd.send({"id": f"t-{i}", "values": values})
            assert r["ok"], r
            if i % 7 == 0:  # polls among the writes, however fast they go
                clean_polls_after_the_writes(peer, 1)
        peer.frozen.add(10)  # acknowledged, not applied: the read back on the same line
        r = cmd.send({"id": "t-21", "values": {"setpoint_hz": 60}})
        assert (r["ok"], r["reason"]) == (False, "not_applied"), r
        clean_polls_after_the_writes(peer)
    finally:
        cmd.close()
    stop(proc)
    assert peer.connections == 1
    log = [pdu[:5] for _, pdu in list(peer.requests)]
    first = log[0]
    starts = [i for i, pdu in enumerate(log) if pdu == first]
    assert len(starts) >= 5
    poll = min((log[a:b] for a, b in itertools.pairwise(starts)), key=len)
    assert len(poll) >= 3  # several requests a poll: something to tear
    assert all(p[0] in (1, 3, 4) for p in poll)
    whole = 0
    for s in starts:
        got = log[s:s + len(poll)]
        if len(got) == len(poll):
            assert got == poll, (s, got)  # no write (nor its reads) inside a poll
            whole += 1
    assert whole >= 5
    assert len(writes_sent(peer)) >= 21


def test_a_budget_refusal_gives_the_poll_connection_back(
        fleet: Fleet, peer: CountingPeer, tmp_path: Path) -> None:  # noqa: F811
    map_file = tmp_path / "wdev.toml"
    map_file.write_text(WRITE_MAP.format(device="", limits="", budget="max_writes_per_hour = 1"))
    broker = fleet.broker()
    proc = start(fleet, broker, None, map_file, tmp_path / "log.sqlite",
                 "--tcp", f"127.0.0.1:{peer.port}")
    cmd = Commander(fleet, broker)
    try:
        assert cmd.send({"id": "b-1", "values": {"setpoint_hz": 49}})["ok"]
        r = cmd.send({"id": "b-2", "values": {"setpoint_hz": 48}})  # refused once lent
        assert (r["ok"], r["reason"]) == (False, "budget"), r
        assert cmd.send({"id": "b-3", "values": {"mode": "run"}})["ok"]
        clean_polls_after_the_writes(peer)  # the polls go on
    finally:
        cmd.close()
    stop(proc)
    assert peer.connections == 1
    assert peer.memory.holding[10] == 4900
