"""The plain profile's write commands (``.../set``) as a careless or hostile
sender makes them: JSON of the wrong shape or types, ids outside 1 to 64
printable characters. Each gets a result with ``ok`` false and reason
``invalid`` or ``range``, and nothing is written; ``pymb log`` in its own
process, Debian's mosquitto, a scripted RTU device on a real pty."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from collectkit import publish
from mqtt_broker import Fleet, fleet, mosquitto  # noqa: F401 (fixtures)
from write_mqtt import SET, Commander, start, stop, writes_sent
from write_peers import WRITE_MAP, FreezingPtyPeer


@pytest.fixture
def peer() -> Iterator[FreezingPtyPeer]:
    with FreezingPtyPeer() as p:
        p.memory.holding[10] = 5000
        p.memory.holding[12] = 0
        yield p


#: (command, the id the result carries, reason)
REFUSED: list[tuple[Any, Any, str]] = [
    ({"id": 5, "values": {"setpoint_hz": 49.5}}, None, "invalid"),
    ({"id": "", "values": {"setpoint_hz": 49.5}}, "", "invalid"),
    ({"id": "x" * 65, "values": {"setpoint_hz": 49.5}}, "x" * 65, "invalid"),
    ({"id": "tab\there", "values": {"setpoint_hz": 49.5}}, "tab\there", "invalid"),
    ({"values": {"setpoint_hz": 49.5}}, None, "invalid"),
    ({"id": "h-1", "values": [["setpoint_hz", 49.5]]}, "h-1", "invalid"),
    ({"id": "h-2", "values": "setpoint_hz=49.5"}, "h-2", "invalid"),
    ({"id": "h-3"}, "h-3", "invalid"),
    ({"id": "h-4", "values": {"setpoint_hz": None}}, "h-4", "invalid"),
    ({"id": "h-5", "values": {"setpoint_hz": [49.5]}}, "h-5", "invalid"),
    ({"id": "h-6", "values": {"setpoint_hz": {"value": 49.5}}}, "h-6", "invalid"),
    ({"id": "h-7", "values": {"setpoint_hz": "49.5 Hz"}}, "h-7", "invalid"),
    ({"id": "h-8", "values": {"mode": 1.5}}, "h-8", "range"),
    ({"id": "h-12", "values": {"setpoint_hz": True}}, "h-12", "invalid"),
    ({"id": "h-13", "values": {"setpoint_hz": "49.5"}}, "h-13", "invalid"),
    ({"id": "h-14", "values": {"relay_2": 2}}, "h-14", "invalid"),
    ({"id": "h-9", "values": {"setpoint_hz": 1e400}}, "h-9", "range"),
    ([{"id": "h-10", "values": {"setpoint_hz": 49.5}}], None, "invalid"),
    ("h-11", None, "invalid"),
]


def test_commands_of_the_wrong_shape_are_refused_and_write_nothing(
        fleet: Fleet, peer: FreezingPtyPeer, tmp_path: Path) -> None:  # noqa: F811
    map_file = tmp_path / "wdev.toml"
    map_file.write_text(WRITE_MAP.format(device="", limits="", budget=""))
    broker = fleet.broker()
    proc = start(fleet, broker, peer, map_file, tmp_path / "log.sqlite")
    cmd = Commander(fleet, broker)
    try:
        # the first result says the logger is subscribed
        assert cmd.send({"id": "ok-1", "values": {"setpoint_hz": 49.0}})["ok"] is True
        sent = len(writes_sent(peer))
        for command, cid, reason in REFUSED:
            raw = json.dumps(command).replace("Infinity", "1e400").encode()
            r = cmd.send(command if cid is not None else {"id": None}, raw=raw)
            assert (r["id"], r["ok"], r["reason"], r["values"]) == (cid, False, reason, {}), \
                (command, r)
            assert r["error"], r
            assert "\n" not in r["error"], r
        assert len(writes_sent(peer)) == sent, "a refused command wrote"
        assert peer.memory.holding[10] == 4900
        # results go at QoS 1, not retained: a late subscriber finds none of them
        assert {q for q, _ in cmd.results.flags} == {1}
        marker = SET.rsplit("/", 1)[0] + "/set/marker"
        publish(broker.port, [(marker, b"m")], retain=True)
        late = fleet.subscribe(broker, SET + "/+", client_id="pymb-test-late")
        late.wait_until(lambda m: m, 15, "the retained marker")
        assert late.snapshot() == [(marker, b"m")]
    finally:
        cmd.close()
    stop(proc)


def test_a_retained_command_from_before_the_logger_is_not_executed(
        fleet: Fleet, peer: FreezingPtyPeer, tmp_path: Path) -> None:  # noqa: F811
    """writes.md: commands are never queued past the moment they could be
    executed. A command the broker held retained from before the logger
    subscribed is refused (reason invalid), once per id; one retained while the
    logger runs is executed when it arrives, and only then."""
    map_file = tmp_path / "wdev.toml"
    map_file.write_text(WRITE_MAP.format(device="", limits="", budget=""))
    broker = fleet.broker()
    db = tmp_path / "log.sqlite"
    stale = {"id": "r-1", "values": {"setpoint_hz": 48.0}}
    publish(broker.port, [(SET, json.dumps(stale).encode())], retain=True)
    results = fleet.subscribe(broker, SET + "/result", client_id="pymb-test-retained")
    proc = start(fleet, broker, peer, map_file, db)
    cmd = Commander(fleet, broker)
    try:
        results.wait_until(lambda m: m, 30, "the result of the retained command")
        r = json.loads(results.snapshot()[0][1])
        assert (r["id"], r["ok"], r["reason"]) == ("r-1", False, "invalid"), r
        assert "retained" in r["error"], r
        # once per id: the same id sent now gets that result
        assert cmd.send(stale)["reason"] == "invalid"
        # retained while the logger runs: it arrives live, and is executed
        live = {"id": "r-2", "values": {"setpoint_hz": 47.0}}
        n = len(results.snapshot())
        publish(broker.port, [(SET, json.dumps(live).encode())], retain=True)
        results.wait_until(lambda m: any(json.loads(p)["id"] == "r-2" for _, p in m[n:]), 30,
                           "the result of the live retained command")
        assert peer.memory.holding[10] == 4700
    finally:
        cmd.close()
    stop(proc)
    sent = len(writes_sent(peer))
    assert sent == 1
    # after a restart the retained r-2 comes again: its result, not a second write
    n = len(results.snapshot())
    proc = start(fleet, broker, peer, map_file, db)
    results.wait_until(lambda m: any(json.loads(p)["id"] == "r-2" for _, p in m[n:]), 30,
                       "r-2's result again")
    again = [json.loads(p) for _, p in results.snapshot()[n:]]
    assert [d["ok"] for d in again if d["id"] == "r-2"] == [True]
    stop(proc)
    assert len(writes_sent(peer)) == sent
