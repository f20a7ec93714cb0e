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
from mqtt_broker import Fleet, fleet, mosquitto  # noqa: F401 (fixtures)
from write_mqtt import Commander, start, stop, writes_sent
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
    finally:
        cmd.close()
    stop(proc)
