"""Sparkplug B DCMD writes against independent parts, with real processes
and signals: ``pymb log --mqtt-profile sparkplug`` SIGKILLed between a
DCMD's write and its answer (the DCMD on record before the write; sent
again after the restart it is answered from the record with a DDATA of the
current values and never written twice), and DCMDs written to pymodbus's
Modbus TCP server (read back by pymb's own client too) and to Debian's
libmodbus server (tests/libmodbus_server.c) on a pseudo-terminal (RTU) and
on TCP, where it serves one connection at a time: the write goes over the
logger's poll connection, between two polls."""

from __future__ import annotations

import signal
import sqlite3
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from mqtt_broker import Fleet, fleet, mosquitto, sparkplug_pb  # noqa: F401 (fixtures)
from sparkplug_host import DEVICE, DOUBLE, UINT16, Host, start
from wire_peers import build_libmodbus_server, libmodbus_server, pymodbus_server
from write_mqtt import rows, stop, writes_sent
from write_peers import WRITE_MAP, FreezingPtyPeer

import pymb

pytest.importorskip("paho.mqtt.client")

MODE = b"\x00\x0c"  #: the mode register (12)


@pytest.fixture
def map_file(tmp_path: Path) -> Path:
    path = tmp_path / "wdev.toml"
    path.write_text(WRITE_MAP.format(device="", limits="", budget=""))
    return path


@pytest.fixture
def peer() -> Iterator[FreezingPtyPeer]:
    with FreezingPtyPeer() as p:
        p.memory.holding[10] = 5000  # setpoint_hz 50.00
        p.memory.holding[12] = 0  # mode stop
        yield p


def commands(db: Path) -> list[tuple[str, str | None]]:
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    try:
        return con.execute("SELECT command_id, result FROM write_commands").fetchall()
    finally:
        con.close()


def test_sigkill_between_a_dcmd_write_and_its_answer_never_writes_twice(
        fleet: Fleet, peer: FreezingPtyPeer, map_file: Path, tmp_path: Path,  # noqa: F811
        sparkplug_pb: Any) -> None:  # noqa: F811
    broker = fleet.broker()
    db = tmp_path / "log.sqlite"
    wrote = threading.Event()

    def hold_the_write(slave: int, pdu: bytes,
                       normal: bytes | None) -> list[tuple[float, bytes]] | None:
        if pdu[0] == 6 and pdu[1:3] == MODE:  # applied, never answered
            wrote.set()
            return []
        return None

    host = Host(fleet, broker, sparkplug_pb)
    # a long timeout: the held write is still waiting for its reply at the kill
    line = ("--port", peer.port, "--baud", "19200", "--timeout", "30")
    proc = start(fleet, broker, peer, map_file, db, *line)
    try:
        aliases = {m.name: m.alias for m in host.birth().metrics}
        peer.hook = hold_the_write
        stamp = host.stamp + 1000
        host.dcmd(("mode", UINT16, 1), seq=3, timestamp=stamp)
        assert wrote.wait(60), "the write never came"
        proc.send_signal(signal.SIGKILL)
        proc.communicate(timeout=30)
        cid = f"sparkplug:{DEVICE}:{stamp}:3"
        assert commands(db) == [(cid, None)]  # on record before the write, no result
        peer.hook = None
        n = len(host.sub.snapshot())
        proc = start(fleet, broker, peer, map_file, db, *line)
        host.sub.wait_until(lambda ms: any("/DBIRTH/" in t for t, _ in ms[n:]), 60,
                            "the DBIRTH after the restart")

        def mode_run(ms: list[tuple[str, bytes]]) -> bool:  # a poll after the restart has it
            return any(m.alias == aliases["mode"] and m.int_value == 1
                       for kind in ("DBIRTH", "DDATA") for p in host.decoded(kind, n, ms)
                       for m in p.metrics)
        host.sub.wait_until(mode_run, 60, "the mode polled after the restart")
        n = len(host.sub.snapshot())
        host.dcmd(("mode", UINT16, 1), seq=3, timestamp=stamp)  # the host sends it again
        assert host.answer(n, aliases) == {"mode": 1}  # what the device holds now
        assert len([p for p in writes_sent(peer) if p[1:3] == MODE]) == 1
        # a third time: answered from the record's result, still not written
        n = len(host.sub.snapshot())
        host.dcmd(("mode", UINT16, 1), seq=3, timestamp=stamp)
        assert host.answer(n, aliases) == {"mode": 1}
        assert len([p for p in writes_sent(peer) if p[1:3] == MODE]) == 1
    finally:
        host.close()
    stop(proc)
    ((got_id, result),) = commands(db)
    assert got_id == cid
    assert result is not None
    assert '"reason":"device"' in result


def dcmd_writes_and_reads_back(fleet: Fleet, sparkplug_pb: Any, map_file: Path,  # noqa: F811
                               db: Path, line: list[str], unit: int) -> None:
    """DCMDs by name and by alias to the device on ``line``: DDATA read back;
    a refused metric writes nothing; the record."""
    broker = fleet.broker()
    host = Host(fleet, broker, sparkplug_pb)
    proc = start(fleet, broker, None, map_file, db, *line, unit=unit)
    try:
        aliases = {m.name: m.alias for m in host.birth().metrics}
        n = len(host.sub.snapshot())
        host.dcmd(("setpoint_hz", DOUBLE, 49.5), (aliases["mode"], UINT16, 1))
        assert host.answer(n, aliases) == {"setpoint_hz": 49.5, "mode": 1}
        n = len(host.sub.snapshot())
        host.dcmd(("setpoint_hz", DOUBLE, 70.0))  # out of range: nothing written
        assert host.answer(n, aliases) == {"setpoint_hz": 49.5}
    finally:
        host.close()
    stop(proc)
    got = [(r[3], r[4], r[7], r[8]) for r in rows(db)]
    assert got == [("setpoint_hz", "49.5", 1, None), ("mode", "1", 1, None),
                   ("setpoint_hz", "70.0", 0, "range")]


def test_dcmd_against_pymodbus_on_the_tcp_loop(fleet: Fleet, sparkplug_pb: Any,  # noqa: F811
                                               map_file: Path, tmp_path: Path) -> None:
    pytest.importorskip("pymodbus")
    with pymodbus_server("tcp") as port:
        dcmd_writes_and_reads_back(fleet, sparkplug_pb, map_file, tmp_path / "log.sqlite",
                                   ["--tcp", f"127.0.0.1:{port}"], 1)
        with pymb.TcpClient("127.0.0.1", port, timeout=2.0) as c:  # 11 is 7 * 11
            assert list(c.read_holding_registers(10, 3, slave=1)) == [4950, 77, 1]


@pytest.fixture(scope="module")
def libmodbus_exe(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return build_libmodbus_server(tmp_path_factory.mktemp("libmodbus"))


def test_dcmd_against_libmodbus_on_a_serial_line(fleet: Fleet, sparkplug_pb: Any,  # noqa: F811
                                                 map_file: Path, tmp_path: Path,
                                                 libmodbus_exe: Path) -> None:
    # the DDATA carries what libmodbus answered to the reads after the writes
    with libmodbus_server(libmodbus_exe, "rtu") as where:
        dcmd_writes_and_reads_back(fleet, sparkplug_pb, map_file, tmp_path / "log.sqlite",
                                   ["--port", where, "--baud", "19200"], 17)


def test_dcmd_over_the_poll_connection_of_a_one_connection_server(
        fleet: Fleet, sparkplug_pb: Any, map_file: Path, tmp_path: Path,  # noqa: F811
        libmodbus_exe: Path) -> None:
    # libmodbus's server serves one connection at a time (the next waits in the
    # listen queue until it closes): the TCP loop's polls hold it, so a write on a
    # second connection would never be answered; the writes go on the poll connection
    with libmodbus_server(libmodbus_exe, "tcp") as where:
        dcmd_writes_and_reads_back(fleet, sparkplug_pb, map_file, tmp_path / "log.sqlite",
                                   ["--tcp", f"127.0.0.1:{where}"], 17)
        with pymb.TcpClient("127.0.0.1", int(where), timeout=2.0) as c:  # 11 is 3 * 11
            assert list(c.read_holding_registers(10, 3, slave=17)) == [4950, 33, 1]
