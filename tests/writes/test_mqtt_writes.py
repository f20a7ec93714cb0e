"""Write commands over MQTT (the plain profile's ``.../set`` and
``.../set/result``) end to end: ``pymb log`` in its own process, Debian's
mosquitto, a paho client that publishes commands and reads results, and a
scripted RTU device on a real pseudo-terminal that logs every request and
can acknowledge a write without applying it. Once per id across a restart
and a SIGKILL between the write and its result; every refusal sends no
write; the ``writes`` view."""

from __future__ import annotations

import json
import signal
import subprocess
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import PYMB, PYMB_ENV, run_pymb, wait_until
from mqtt_broker import Fleet, fleet, mosquitto  # noqa: F401 (fixtures)
from wire_peers import pymodbus_server
from write_mqtt import SET, WRITES, Commander, rows, start, stop, writes_sent
from write_peers import WRITE_MAP, FreezingPtyPeer

import pymb

paho = pytest.importorskip("paho.mqtt.client")

@pytest.fixture
def peer() -> Iterator[FreezingPtyPeer]:
    with FreezingPtyPeer() as p:
        p.memory.holding[10] = 5000
        p.memory.holding[12] = 0
        yield p


@pytest.fixture
def map_file(tmp_path: Path) -> Path:
    path = tmp_path / "wdev.toml"
    path.write_text(WRITE_MAP.format(device="", limits="", budget="max_writes_per_hour = 3"))
    return path


def test_set_result_refusals_once_per_id_and_the_record(fleet: Fleet, peer: FreezingPtyPeer,  # noqa: F811
                                                         map_file: Path, tmp_path: Path) -> None:
    broker = fleet.broker()
    db = tmp_path / "log.sqlite"
    proc = start(fleet, broker, peer, map_file, db)
    cmd = Commander(fleet, broker)
    try:
        r = cmd.send({"id": "c-1", "values": {"setpoint_hz": 49.5, "mode": "run"}})
        assert (r["ok"], r["values"]) == (True, {"setpoint_hz": 49.5, "mode": "run"})
        assert r["time"].endswith("Z")
        assert list(r) == ["id", "ok", "values", "time"]
        assert peer.memory.holding[10] == 4950
        n = len(writes_sent(peer))
        assert n == 2  # setpoint_hz (10) and mode (12): not adjacent

        for command, reason in [
            ({"id": "c-2", "values": {"setpoint_hz": 70}}, "range"),
            ({"id": "c-3", "values": {"mode": "running"}}, "range"),
            ({"id": "c-4", "values": {"power_limit_pct": 5}}, "not_allowed"),
            ({"id": "c-5", "values": {"firmware": 5}}, "not_allowed"),
            ({"id": "c-6", "values": {"setpont_hz": 50}}, "invalid"),
            ({"id": "c-7", "values": {"setpoint_hz": "fast"}}, "invalid"),
            ({"id": "c-8", "values": {}}, "invalid"),
            ({"id": "c-9", "values": {"setpoint_hz": 50, "mode": 9}}, "range"),
        ]:
            r = cmd.send(command)
            assert (r["ok"], r["reason"], r["values"]) == (False, reason, {}), r
            assert list(r) == ["id", "ok", "reason", "error", "values", "time"]
            assert r["error"]
            assert "\n" not in r["error"]
        assert len(writes_sent(peer)) == n  # not one refusal wrote

        # the same id again, whatever its values: the stored result, nothing written
        again = cmd.send({"id": "c-1", "values": {"setpoint_hz": 46}})
        assert (again["ok"], again["values"]) == (True, {"setpoint_hz": 49.5, "mode": "run"})
        assert len(writes_sent(peer)) == n

        # acknowledged, not applied
        peer.frozen.add(10)
        r = cmd.send({"id": "c-10", "values": {"setpoint_hz": 48}})
        assert (r["ok"], r["reason"]) == (False, "not_applied")
        assert "sent 48, the device holds 49.5" in r["error"]
        peer.frozen.clear()

        # the budget: 3 writes an hour of setpoint_hz (c-1, c-10 counted); a held value is free
        assert cmd.send({"id": "c-11", "values": {"setpoint_hz": 49.5}})["ok"] is True
        assert cmd.send({"id": "c-12", "values": {"setpoint_hz": 47}})["ok"] is True
        n = len(writes_sent(peer))
        r = cmd.send({"id": "c-13", "values": {"setpoint_hz": 46}})
        assert (r["ok"], r["reason"]) == (False, "budget")
        assert r["error"] == ("psu-a: 'setpoint_hz': write budget spent (3 writes per hour); "
                              "nothing was sent")
        assert len(writes_sent(peer)) == n
        r = cmd.send(None, raw=b"not json")
        assert (r["id"], r["ok"], r["reason"]) == (None, False, "invalid")
    finally:
        cmd.close()
    stop(proc)
    got = rows(db)
    assert got[0] == ("mqtt", "c-1", "psu-a", "setpoint_hz", "49.5", "50.0", "49.5", 1, None)
    assert got[1] == ("mqtt", "c-1", "psu-a", "mode", '"run"', '"stop"', '"run"', 1, None)
    assert ("mqtt", "c-2", "psu-a", "setpoint_hz", "70", None, None, 0, "range") in got
    assert [r[1] for r in got].count("c-1") == 2  # the repeat is no new row
    exported = run_pymb("export", "--writes", str(db))
    assert exported.returncode == 0, exported.stderr
    lines = exported.stdout.splitlines()
    assert lines[0] == "time,source,command_id,device,point,requested,before,after,ok,reason"
    assert len(lines) == 1 + len(got)
    assert lines[1].endswith(",mqtt,c-1,psu-a,setpoint_hz,49.5,50.0,49.5,1,")
    applied = sum(r[7] for r in got)
    info = run_pymb("info", str(db))
    assert f"writes      {applied} point(s) applied, {len(got) - applied} refused or failed" \
        in info.stdout

    # once per id across a restart of the logger
    proc = start(fleet, broker, peer, map_file, db)
    cmd = Commander(fleet, broker)
    try:
        n = len(writes_sent(peer))
        again = cmd.send({"id": "c-12", "values": {"setpoint_hz": 45}})
        assert (again["ok"], again["values"]) == (True, {"setpoint_hz": 47.0})
        budget = cmd.send({"id": "c-15", "values": {"setpoint_hz": 45}})
        assert budget["reason"] == "budget"  # the count was kept in the database
        assert len(writes_sent(peer)) == n
    finally:
        cmd.close()
    stop(proc)


def test_sigkill_between_the_write_and_its_result_never_writes_twice(
        fleet: Fleet, peer: FreezingPtyPeer, map_file: Path, tmp_path: Path) -> None:  # noqa: F811
    broker = fleet.broker()
    db = tmp_path / "log.sqlite"
    wrote = threading.Event()

    def hold_the_write(slave: int, pdu: bytes,
                       normal: bytes | None) -> list[tuple[float, bytes]] | None:
        if pdu[0] == 6 and pdu[1:3] == b"\x00\x0c":  # mode: applied, never answered
            wrote.set()
            return []
        return None

    peer.hook = hold_the_write
    proc = start(fleet, broker, peer, map_file, db)
    cmd = Commander(fleet, broker)
    try:
        assert cmd.send({"id": "k-0", "values": {"setpoint_hz": 50}})["ok"]  # subscribed
        cmd.client.publish(SET, json.dumps({"id": "k-1", "values": {"mode": "run"}}), qos=1)
        assert wrote.wait(60), "the write never came"
        proc.send_signal(signal.SIGKILL)
        proc.communicate(timeout=30)
        peer.hook = None
        proc = start(fleet, broker, peer, map_file, db)
        r = cmd.send({"id": "k-1", "values": {"mode": "run"}})
        assert (r["ok"], r["reason"]) == (False, "device")
        assert "not executed again" in r["error"]
        mode_writes = [p for p in writes_sent(peer) if p[1:3] == b"\x00\x0c"]
        assert len(mode_writes) == 1
    finally:
        cmd.close()
    stop(proc)


def test_a_device_on_the_tcp_loop_against_pymodbus(fleet: Fleet, map_file: Path,  # noqa: F811
                                                   tmp_path: Path) -> None:
    pytest.importorskip("pymodbus")
    broker = fleet.broker()
    with pymodbus_server("tcp") as port:
        proc = start(fleet, broker, None, map_file, tmp_path / "log.sqlite",
                     "--tcp", f"127.0.0.1:{port}")
        cmd = Commander(fleet, broker)
        try:
            r = cmd.send({"id": "t-1", "values": {"setpoint_hz": 49.5, "relay_5": True}})
            assert (r["ok"], r["values"]) == (True, {"setpoint_hz": 49.5, "relay_5": True}), r
            with pymb.TcpClient("127.0.0.1", port, timeout=2.0) as c:
                assert list(c.read_holding_registers(10, 1, slave=1)) == [4950]
                assert c.read_holding_registers(20, 1, slave=1)[0] == (7 * 20) | 0x20
        finally:
            cmd.close()
        stop(proc)


def test_an_offline_device_fails_fast_with_reason_device(fleet: Fleet,  # noqa: F811
                                                         map_file: Path,
                                                         tmp_path: Path) -> None:
    broker = fleet.broker()
    with FreezingPtyPeer(slaves={1}) as peer:
        proc = subprocess.Popen(
            [*PYMB, "log", "--map", str(map_file), "--port", peer.port, "--timeout", "0.2",
             "--device", "wdev:1,name=psu-a", "--device", "wdev:2,name=dead",
             "--interval", "0.2", "--out", str(tmp_path / "log.sqlite"),
             "--mqtt", f"mqtt://127.0.0.1:{broker.port}", "--mqtt-node", "n1",
             "--allow-writes", "*/setpoint_hz", "--quiet"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=PYMB_ENV)
        fleet.children.append(proc)
        cmd = Commander(fleet, broker)
        dead = fleet.subscribe(broker, "pymb/n1/dead/set/result", client_id="pymb-test-dead")
        try:
            assert cmd.send({"id": "o-0", "values": {"setpoint_hz": 50}})["ok"]  # subscribed
            # the dead unit misses offline_after (3) polls and is backed off
            wait_until(lambda: sum(1 for s, _ in list(peer.requests) if s == 2) >= 3,
                       "three polls of the dead unit", 30)
            time.sleep(1.0)
            t0 = time.monotonic()
            cmd.client.publish("pymb/n1/dead/set", json.dumps(
                {"id": "o-1", "values": {"setpoint_hz": 50}}), qos=1).wait_for_publish(5)
            dead.wait_until(lambda m: m, 30, "the dead unit's result")
            took = time.monotonic() - t0
            r = json.loads(dead.snapshot()[0][1])
            assert (r["id"], r["ok"], r["reason"]) == ("o-1", False, "device")
            assert took < 5.0
            assert not [p for s, p in list(peer.requests) if s == 2 and p[0] in WRITES]
        finally:
            cmd.close()
        stop(proc, 3)  # exit 3: a device delivered no sample
