"""The broker's own redelivery of write commands (the plain profile over MQTT
5): ``pymb log`` keeps a persistent session and acknowledges a command only
once it is answered, so a command delivered to a logger that is SIGKILLed
before its answer is delivered again by mosquitto when the logger comes back
with the same client id, and answered then: from the record when it was on
record (never written twice), executed once when it was not. A clean stop
ends the session: a command sent while the logger is stopped is not executed
when it starts again. Real processes and signals, Debian's mosquitto, paho,
the scripted RTU device on a pty that logs every request."""

from __future__ import annotations

import json
import signal
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from mqtt_broker import Fleet, fleet, mosquitto  # noqa: F401 (fixtures)
from write_mqtt import SET, Commander, start, stop, writes_sent
from write_peers import WRITE_MAP, FreezingPtyPeer

pytest.importorskip("paho.mqtt.client")

MODE = b"\x00\x0c"  #: the mode register (12)
SETPOINT = b"\x00\x0a"  #: the setpoint_hz register (10)


@pytest.fixture
def peer() -> Iterator[FreezingPtyPeer]:
    with FreezingPtyPeer() as p:
        p.memory.holding[10] = 5000
        p.memory.holding[12] = 0
        yield p


@pytest.fixture
def map_file(tmp_path: Path) -> Path:
    path = tmp_path / "wdev.toml"
    path.write_text(WRITE_MAP.format(device="", limits="", budget=""))
    return path


def result_of(cmd: Commander, cid: str, timeout: float) -> Any:
    """The first result with ``cid``, waited for without publishing anything."""
    def found(msgs: list[tuple[str, bytes]]) -> Any:
        for _, p in msgs:
            doc = json.loads(p)
            if doc.get("id") == cid:
                return doc
        return None
    return cmd.results.wait_until(found, timeout, f"the result of {cid}")


def register_writes(peer: FreezingPtyPeer, register: bytes) -> list[bytes]:
    return [p for p in writes_sent(peer) if p[1:3] == register]


def test_a_command_the_broker_delivers_again_after_a_sigkill_is_answered_once(
        fleet: Fleet, peer: FreezingPtyPeer, map_file: Path, tmp_path: Path) -> None:  # noqa: F811
    broker = fleet.broker()
    db = tmp_path / "log.sqlite"
    wrote = threading.Event()

    def hold_the_write(slave: int, pdu: bytes,
                       normal: bytes | None) -> list[tuple[float, bytes]] | None:
        if pdu[0] == 6 and pdu[1:3] == MODE:  # applied, never answered
            wrote.set()
            return []
        return None

    peer.hook = hold_the_write
    # a long timeout: the held write is still waiting for its reply at the kill
    line = ("--port", peer.port, "--baud", "19200", "--timeout", "30")
    proc = start(fleet, broker, peer, map_file, db, *line)
    cmd = Commander(fleet, broker)
    try:
        assert cmd.send({"id": "r-0", "values": {"setpoint_hz": 50}})["ok"]  # subscribed
        # each published once, by this test: any later delivery is the broker's
        cmd.client.publish(SET, json.dumps({"id": "r-1", "values": {"mode": "run"}}),
                           qos=1).wait_for_publish(5)
        assert wrote.wait(60), "the write never came"
        # r-2 waits behind r-1, unanswered (in the logger or at the broker)
        cmd.client.publish(SET, json.dumps({"id": "r-2", "values": {"setpoint_hz": 47}}),
                           qos=1).wait_for_publish(5)
        proc.send_signal(signal.SIGKILL)
        proc.communicate(timeout=30)
        assert not [p for _, p in cmd.results.snapshot() if b'"r-1"' in p or b'"r-2"' in p]
        peer.hook = None
        proc = start(fleet, broker, peer, map_file, db, *line)  # the same client id, session kept
        r1 = result_of(cmd, "r-1", 60)
        assert (r1["ok"], r1["reason"]) == (False, "device"), r1
        assert "not executed again" in r1["error"]
        r2 = result_of(cmd, "r-2", 60)
        assert (r2["ok"], r2["values"]) == (True, {"setpoint_hz": 47.0}), r2
        assert len(register_writes(peer, MODE)) == 1  # r-1 written once, before the kill
        assert [p for p in register_writes(peer, SETPOINT) if p[3:5] == (4700).to_bytes(2, "big")] \
            == [b"\x06" + SETPOINT + (4700).to_bytes(2, "big")]  # r-2 written once, after it
        assert peer.memory.holding[10] == 4700
        # each answered once: the broker had it acknowledged once answered
        ids = [json.loads(p)["id"] for _, p in cmd.results.snapshot()]
        assert (ids.count("r-1"), ids.count("r-2")) == (1, 1), ids
    finally:
        cmd.close()
    stop(proc)


def test_a_clean_stop_ends_the_session_no_command_waits_for_the_logger(
        fleet: Fleet, peer: FreezingPtyPeer, map_file: Path, tmp_path: Path) -> None:  # noqa: F811
    broker = fleet.broker()
    db = tmp_path / "log.sqlite"
    proc = start(fleet, broker, peer, map_file, db)
    cmd = Commander(fleet, broker)
    try:
        assert cmd.send({"id": "s-0", "values": {"setpoint_hz": 50}})["ok"]
        stop(proc)
        cmd.client.publish(SET, json.dumps({"id": "s-1", "values": {"setpoint_hz": 46}}),
                           qos=1).wait_for_publish(5)
        proc = start(fleet, broker, peer, map_file, db)
        # a command after the restart is answered; one queued for the old session came
        # before it if at all (one session's messages keep their order)
        assert cmd.send({"id": "s-2", "values": {"mode": "run"}})["ok"]
        ids = [json.loads(p)["id"] for _, p in cmd.results.snapshot()]
        assert "s-1" not in ids
        assert not [p for p in register_writes(peer, SETPOINT) if p[3:5] == b"\x11\xf8"]  # 4600
        assert peer.memory.holding[10] == 5000
    finally:
        cmd.close()
    stop(proc)
