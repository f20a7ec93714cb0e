"""Write commands under a flood and through a broker restart, end to end
(``pymb log`` in its own process, mosquitto, paho, the scripted RTU device
on a pty): 1,000 commands in about a second, most refused, neither stop the
polling nor grow the logger's memory; after a broker restart commands are
taken again and an id already answered is answered from the record."""

from __future__ import annotations

import itertools
import json
import sqlite3
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import wait_until
from mqtt_broker import Fleet, fleet, mosquitto  # noqa: F401 (fixtures)
from write_mqtt import WRITES, Commander, clean_polls_after_the_writes, start, stop, writes_sent
from write_peers import WRITE_MAP, FreezingPtyPeer

pytest.importorskip("paho.mqtt.client")


@pytest.fixture
def peer() -> Iterator[FreezingPtyPeer]:
    with FreezingPtyPeer() as p:
        p.memory.holding[10] = 5000
        yield p


@pytest.fixture
def map_file(tmp_path: Path) -> Path:
    path = tmp_path / "wdev.toml"
    path.write_text(WRITE_MAP.format(device="", limits="", budget=""))
    return path


def rss_kb(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise AssertionError("no VmRSS")


def samples(db: Path) -> int:
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    try:
        return int(con.execute("SELECT COUNT(*) FROM samples").fetchone()[0])
    except sqlite3.Error:
        return 0
    finally:
        con.close()


def test_a_flood_of_commands_neither_stops_polling_nor_grows_memory(
        fleet: Fleet, peer: FreezingPtyPeer, map_file: Path, tmp_path: Path) -> None:  # noqa: F811
    broker = fleet.broker()
    db = tmp_path / "log.sqlite"
    proc = start(fleet, broker, peer, map_file, db)
    cmd = Commander(fleet, broker)
    try:
        assert cmd.send({"id": "f-0", "values": {"setpoint_hz": 49}})["ok"]

        def polls() -> int:
            return sum(1 for _, p in list(peer.requests) if p[0] in (1, 3, 4))

        def flood(first: int, n: int) -> None:
            for i in range(first, first + n):  # most refused: range and not allowed
                values: dict[str, object] = {"setpoint_hz": 99} if i % 2 else \
                    {"power_limit_pct": 5}
                if i % 100 == 0:
                    values = {"mode": "run" if i % 200 else "stop"}  # a few real writes
                cmd.client.publish("pymb/n1/psu-a/set",
                                   json.dumps({"id": f"f-{i}", "values": values}), qos=1)

        flood(1, 1000)  # a warm-up flood: the memory measured after it
        wait_until(lambda: len(cmd.results.snapshot()) >= 1001, "the first flood answered", 120)
        before_rss = rss_kb(proc.pid)
        before_polls = polls()
        t0 = time.monotonic()
        flood(1001, 1000)
        sent_in = time.monotonic() - t0
        # the polling goes on while the commands are answered
        wait_until(lambda: polls() >= before_polls + 10, "polls during the flood", 30)
        wait_until(lambda: len(cmd.results.snapshot()) >= 2001, "the second flood answered", 120)
        after_rss = rss_kb(proc.pid)
        results = [json.loads(p) for _, p in cmd.results.snapshot()]
        reasons = {r.get("reason") for r in results}
        assert reasons == {None, "range", "not_allowed"}, reasons
        assert len({r["id"] for r in results}) == 2001  # each once
        assert sent_in < 10
        assert after_rss - before_rss < 8 * 1024, (before_rss, after_rss)
        # a sample stored for each of the polls, still
        assert samples(db) > 0
        mode_writes = [p for p in writes_sent(peer) if p[1:3] == b"\x00\x0c"]
        assert len(mode_writes) == 20  # f-100 .. f-2000, each once
        assert all(p[0] in WRITES for p in mode_writes)
    finally:
        cmd.close()
    stop(proc)


def test_commands_after_a_broker_restart_and_once_per_id(
        fleet: Fleet, peer: FreezingPtyPeer, map_file: Path, tmp_path: Path) -> None:  # noqa: F811
    broker = fleet.broker()
    db = tmp_path / "log.sqlite"
    proc = start(fleet, broker, peer, map_file, db)
    cmd = Commander(fleet, broker)
    try:
        assert cmd.send({"id": "b-1", "values": {"setpoint_hz": 48}})["ok"]
        n = len(writes_sent(peer))
        broker.stop()
        time.sleep(1.0)
        broker.start()
        again = cmd.send({"id": "b-1", "values": {"setpoint_hz": 47}}, timeout=60)
        assert (again["ok"], again["values"]) == (True, {"setpoint_hz": 48.0})
        assert len(writes_sent(peer)) == n
        r = cmd.send({"id": "b-2", "values": {"setpoint_hz": 47}}, timeout=60)
        assert (r["ok"], r["values"]) == (True, {"setpoint_hz": 47.0})
        assert peer.memory.holding[10] == 4700
    finally:
        cmd.close()
    stop(proc)


def test_writes_go_between_polls_never_inside_one(
        fleet: Fleet, peer: FreezingPtyPeer, map_file: Path, tmp_path: Path) -> None:  # noqa: F811
    broker = fleet.broker()
    proc = start(fleet, broker, peer, map_file, tmp_path / "log.sqlite")
    cmd = Commander(fleet, broker)
    try:
        assert cmd.send({"id": "p-0", "values": {"setpoint_hz": 49}})["ok"]
        for i in range(1, 41):
            values = {"setpoint_hz": 45 + i % 10} if i % 2 else {"mode": "run" if i % 4 else
                                                                 "stop"}
            r = cmd.send({"id": f"p-{i}", "values": values})
            assert r["ok"], r
        clean_polls_after_the_writes(peer)
    finally:
        cmd.close()
    stop(proc)
    log = [pdu[:5] for _, pdu in list(peer.requests)]
    # a poll is the same run of reads each time; find it from the first reads logged
    first = log[0]
    starts = [i for i, pdu in enumerate(log) if pdu == first]
    assert len(starts) >= 5
    # (the shortest run between two starts: a command may come between the first two)
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
    assert len(writes_sent(peer)) >= 40
