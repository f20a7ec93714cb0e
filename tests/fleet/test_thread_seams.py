"""No SQLite connection crosses a thread between the logger's writer and the
MQTT forwarder: the writer hands the forwarder what it wrote as data, the
forwarder reads the backlog on a connection of its own and hands its cursor
and state to the writer for its next batch (pymb.store.handoff).

Every connection made here is made with ``check_same_thread=True``: SQLite's
Python module then raises ProgrammingError when a thread uses a connection
another thread made, and the forwarder's thread ends with that error (a
command desk's record: the command is refused as not put on record)."""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import threading
from array import array
from pathlib import Path
from typing import Any

import pytest

pytest.register_assert_rewrite("mqtt_broker")
from conftest import wait_until  # noqa: E402
from mqtt_broker import Fleet, db_count, db_ids, plain_ids  # noqa: E402
from write_mqtt import Commander, rows  # noqa: E402
from write_peers import WRITE_MAP, FreezingTcpPeer  # noqa: E402

from pymb.cli import main  # noqa: E402
from pymb.devices import CoolProStatus, CoolProTelemetry, decode_hub  # noqa: E402
from pymb.errors import OutputError  # noqa: E402
from pymb.fleet import ForwardingSink, MqttConfig  # noqa: E402
from pymb.fleet.forwarder import Forwarder  # noqa: E402
from pymb.logger import BusConfig, DeviceConfig, LogConfig, Logger  # noqa: E402
from pymb.store import DeviceInfo, Sample, SqliteSink  # noqa: E402

pytest_plugins = ["mqtt_broker"]

_connect = sqlite3.connect


@pytest.fixture
def one_thread_connections(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every sqlite3 connection made during the test checks its thread."""
    def connect(*args: Any, **kw: Any) -> sqlite3.Connection:
        kw["check_same_thread"] = True
        con: sqlite3.Connection = _connect(*args, **kw)
        return con

    monkeypatch.setattr(sqlite3, "connect", connect)
    made = sqlite3.connect(":memory:")
    failed: list[BaseException] = []

    def use() -> None:
        try:
            made.execute("SELECT 1")
        except sqlite3.ProgrammingError as e:
            failed.append(e)

    t = threading.Thread(target=use)
    t.start()
    t.join()
    made.close()
    assert failed, "a connection used from another thread did not fail: the check is off"


def _run(fleet: Fleet, db: Path, cfg: MqttConfig,
         during: Any) -> tuple[Forwarder, SqliteSink]:
    """Log the simulated CoolPro into ``db`` and forward it as ``cfg`` says;
    ``during(logger)`` runs in a thread of its own and stops the logger."""
    sim = fleet.simulator("coolpro")
    bus = BusConfig("bus1", tcp=sim.endpoint, timeout=1.0, interval=0.02,
                    devices=[DeviceConfig("coolpro", 40)])
    sink = SqliteSink(db)
    fw = Forwarder(str(db), cfg, writer=sink)
    fw.start()
    logger = Logger(LogConfig([bus], "sqlite", str(db)), sink=ForwardingSink(sink, fw))
    t = threading.Thread(target=during, args=(logger,), daemon=True)
    t.start()
    try:
        logger.run(60)
    finally:
        t.join(60)
    return fw, sink


def _cursor(db: Path) -> int:
    con = sqlite3.connect(db)
    try:
        return int(con.execute("SELECT COALESCE(MAX(sample_id), 0) FROM outbox").fetchone()[0])
    finally:
        con.close()


def test_live_then_an_outage_that_outlasts_the_writer(
        fleet: Fleet, tmp_path: Path, one_thread_connections: None) -> None:
    """Samples go out live (from the writer's handoff); the broker stops, the
    logger ends while it is away (the writer closes with samples unsent), the
    broker comes back: the forwarder sends the backlog from its own
    connection and writes its cursor itself. Every sample arrives."""
    broker = fleet.broker()
    sub = fleet.subscribe(broker, "pymb/#")
    db = tmp_path / "log.sqlite"

    def during(logger: Logger) -> None:
        try:
            sub.wait_until(lambda m: len(plain_ids(m)) >= 50, 30, "50 samples live")
            broker.stop()
            before = db_count(db)
            wait_until(lambda: db_count(db) >= before + 50, "50 samples logged while down", 30)
        finally:
            logger.stop()

    fw, sink = _run(fleet, db, MqttConfig(broker.url, node="seams"), during)
    assert sink.closed
    try:
        assert fw.error is None, fw.error
        broker.start()
        want = db_ids(db)
        sub.wait_until(lambda m: set(plain_ids(m)) >= want, 60, "every sample after the outage")
    finally:
        fw.stop(10)
        fw.join(20)
    assert fw.error is None, fw.error
    assert _cursor(db) == max(want)


def test_sparkplug_state_goes_in_with_the_writers_batch(
        fleet: Fleet, tmp_path: Path, one_thread_connections: None) -> None:
    """Sparkplug's bdSeq is written durably before each CONNECT: handed to the
    writer, committed with its batch; births read the devices and their
    newest samples (the open batch's too) without the writer's connection."""
    broker = fleet.broker()
    sub = fleet.subscribe(broker, "spBv1.0/#")
    db = tmp_path / "log.sqlite"

    def during(logger: Logger) -> None:
        try:
            sub.wait_until(lambda m: sum("/DDATA/" in t for t, _ in m) >= 30, 30,
                           "30 DDATA")
        finally:
            logger.stop()

    cfg = MqttConfig(broker.url, profile="sparkplug", group="g", node="seams")
    fw, _sink = _run(fleet, db, cfg, during)
    fw.stop(10)
    fw.join(20)
    assert fw.error is None, fw.error
    kinds = [t.split("/")[2] for t, _ in sub.snapshot()]
    assert kinds[:2] == ["NBIRTH", "DBIRTH"]
    con = sqlite3.connect(db)
    try:
        assert con.execute("SELECT value FROM fleet_state").fetchall() == [(0,)]
    finally:
        con.close()


def _by_topic(messages: list[tuple[str, bytes]]) -> dict[str, list[int]]:
    """The plain profile's data messages: topic -> sample ids, as they came."""
    out: dict[str, list[int]] = {}
    for t, p in messages:
        if not t.endswith(("/status", "/meta")):
            out.setdefault(t, []).append(json.loads(p)["sample"])
    return out


def _on_disk(db: Path, prefix: str) -> dict[str, list[int]]:
    """The file's samples as the plain profile's topics would carry them."""
    con = sqlite3.connect(db)
    try:
        out: dict[str, list[int]] = {}
        for name, sid in con.execute("SELECT d.name, s.id FROM samples s "
                                     "JOIN devices d ON d.id = s.device_id ORDER BY s.id"):
            out.setdefault(f"{prefix}/{name}", []).append(int(sid))
        return out
    finally:
        con.close()


def test_a_batch_rolled_back_is_not_published(
        fleet: Fleet, tmp_path: Path, one_thread_connections: None) -> None:
    """A sample of one device is written; the batch is rolled back (a write
    command's record fails inside it: the disk is full); the next batch
    gives that device's id to another device, whose samples the forwarder
    takes from the open batch. It publishes exactly what the file has,
    under the right device's name, and nothing of the rolled-back batch."""
    broker = fleet.broker()
    sub = fleet.subscribe(broker, "pymb/#")
    db = tmp_path / "rb.sqlite"
    sink = SqliteSink(db)
    fw = Forwarder(str(db), MqttConfig(broker.url, node="seams"), writer=sink)
    out = ForwardingSink(sink, fw)
    psu = DeviceInfo("bus1", "/dev/null", "coolpro", 40, "psu")
    hub = DeviceInfo("bus1", "/dev/null", "hub", 1, "hub-1")
    regs = array("H", [245, 245, 240, 241, 261, 0, 0, 0])
    out.write(Sample(psu, 1_700_000_000.0, 0.0, CoolProTelemetry(
        24.5, 2.45, 24.0, 2.41, 26.1, 0, CoolProStatus(0), regs)))

    def disk_full(con: sqlite3.Connection) -> None:
        raise sqlite3.OperationalError("database or disk is full")

    with pytest.raises(OutputError):
        out.sink.in_batch(disk_full, True)
    fw.start()
    try:
        sub.wait_until(lambda m: ("pymb/seams/status", b"online") in m, 30, "the forwarder")
        # its live lane starts after the births are acknowledged: what is written
        # before that is the catch-up lane's, which reads committed samples only
        wait_until(lambda: fw.status().connected, "the forwarder's live lane", 30)
        for i in range(3):  # taken live, from the open batch
            out.write(Sample(hub, 1_700_000_001.0 + i, 1.0 + i,
                             decode_hub(array("H", [200 + i] * 700))))
        sub.wait_until(lambda m: len(plain_ids(m)) >= 3, 30, "3 samples")
        out.commit()
        # acknowledged, its cursor handed over: the writer's last batch takes it
        wait_until(lambda: fw.status().cursor >= 4, "the cursor past them", 30)
        out.close()
    finally:
        fw.stop(10)
        fw.join(20)
    assert fw.error is None, fw.error
    assert _on_disk(db, "pymb/seams") == {"pymb/seams/hub-1": [2, 3, 4]}
    assert _by_topic(sub.snapshot()) == _on_disk(db, "pymb/seams")
    assert _cursor(db) == 4


def test_write_commands_are_recorded_by_the_writers_thread(
        fleet: Fleet, tmp_path: Path, one_thread_connections: None) -> None:
    """``pymb log --mqtt --allow-writes`` in this process (its writer in this
    thread): MQTT set commands, from paho's thread to the command desk's,
    are executed once per id, put on record and counted against their
    budget by the writer's thread, on its connection."""
    map_file = tmp_path / "wdev.toml"
    map_file.write_text(WRITE_MAP.format(device="", limits="",
                                         budget="max_writes_per_hour = 3"))
    db = tmp_path / "log.sqlite"
    broker = fleet.broker()
    results: list[dict[str, Any]] = []
    failed: list[BaseException] = []
    with FreezingTcpPeer() as peer:
        peer.memory.holding[10] = 5000
        cmd = Commander(fleet, broker)

        def commands() -> None:
            try:
                for i in range(4):  # the fourth: the budget of 3 an hour is spent
                    results.append(cmd.send({"id": f"s-{i}", "values": {"setpoint_hz": 46 + i}}))
                results.append(cmd.send({"id": "s-0", "values": {"setpoint_hz": 60}}))
            except BaseException as e:
                failed.append(e)
            finally:
                os.kill(os.getpid(), signal.SIGTERM)  # the run's handler: a clean stop

        # the run installs its own; a SIGTERM after it ended must not end pytest
        before = signal.signal(signal.SIGTERM, lambda *_: None)
        t = threading.Thread(target=commands, daemon=True)
        t.start()
        try:
            code = main(["log", "--map", str(map_file), "--tcp", f"127.0.0.1:{peer.port}",
                         "--device", "wdev:1,name=psu-a", "--interval", "0.2", "--out", str(db),
                         "--mqtt", f"mqtt://127.0.0.1:{broker.port}", "--mqtt-node", "n1",
                         "--allow-writes", "psu-a/setpoint_hz", "--seconds", "120", "--quiet"])
        finally:
            t.join(30)
            signal.signal(signal.SIGTERM, before)
            cmd.close()
    assert not failed, failed
    assert code == 0
    assert [(r["id"], r["ok"], r.get("reason")) for r in results] == [
        ("s-0", True, None), ("s-1", True, None), ("s-2", True, None),
        ("s-3", False, "budget"), ("s-0", True, None)]
    assert results[4] == results[0]  # once per id: its stored result, published again
    assert peer.memory.holding[10] == 4800
    assert [(r[1], r[7], r[8]) for r in rows(db)] == [
        ("s-0", 1, None), ("s-1", 1, None), ("s-2", 1, None), ("s-3", 0, "budget")]
