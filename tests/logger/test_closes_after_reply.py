"""A Modbus TCP device that closes the connection after each reply (some
drives and gateways do), logged by ``pymb log`` as a user runs it: every
poll is read, a request per connection; the "once after connect" group is
read once in the run, not once a connection; a point the device refuses is
asked for a few times in the run, not again on each connection; and no
fault is counted for what is the device's way of working.

The device is tests/hostile_gateway.py's scripted gateway (register ``a``
of unit ``u`` holds ``100 u + a``), answering register 900 with exception
02 and closing each connection right after its reply."""

from __future__ import annotations

import json
import socket
import sqlite3
import threading
from contextlib import closing
from pathlib import Path

import pytest
from conftest import run_pymb
from hostile_gateway import Hostile, Request, good

from pymb import ModbusConnectionError, TcpClient
from pymb.devices.mapreading import MapReading
from pymb.store import samples_after

MAP = '''schema = "pymb.map/1"
[device]
id = "one-shot"
table = "holding"
[groups]
fast = { interval = 0.25 }
info = { interval = 0 }
[[point]]
name = "a"
address = 0
type = "u16"
group = "fast"
[[point]]
name = "b"
address = 300
type = "u16"
group = "fast"
[[point]]
name = "c"
address = 600
type = "u16"
group = "fast"
[[point]]
name = "missing"
address = 900
type = "u16"
group = "fast"
[[point]]
name = "serial"
address = 1000
type = "u16"
group = "info"
'''


class OneShot:
    """Answers one request per connection, then closes it; counts the
    requests by register."""

    def __init__(self) -> None:
        self.asked: dict[int, int] = {}
        self.lock = threading.Lock()
        self.gw = Hostile(self.script)

    def script(self, n: int, req: Request, conn: socket.socket) -> None:
        tid, unit, fc, address, _ = req
        with self.lock:
            self.asked[address] = self.asked.get(address, 0) + 1
        if address == 900:
            reply = tid.to_bytes(2, "big") + b"\x00\x00\x00\x03" + bytes((unit, fc | 0x80, 2))
        else:
            reply = good(*req)
        conn.sendall(reply)
        conn.shutdown(socket.SHUT_RDWR)


@pytest.mark.parametrize("pipeline", [1, 4])
def test_a_device_that_closes_after_each_reply_is_polled(tmp_path: Path, pipeline: int) -> None:
    (tmp_path / "one-shot.toml").write_text(MAP)
    dev = OneShot()
    db = tmp_path / "log.sqlite"
    (tmp_path / "log.toml").write_text(
        f'maps = ["one-shot.toml"]\n[[bus]]\ntcp = "127.0.0.1:{dev.gw.port}"\n'
        f'pipeline = {pipeline}\n[[bus.device]]\ntype = "one-shot"\naddress = 1\n')
    try:
        r = run_pymb("log", "--config", str(tmp_path / "log.toml"), "--seconds", "4",
                     "--out", str(db), timeout=120)
    finally:
        dev.gw.close()
    assert r.returncode == 0, r.stderr
    got = [s.data for s in samples_after(db, 0, limit=100_000)]
    assert all(isinstance(d, MapReading) for d in got)
    fast = [d for d in got if isinstance(d, MapReading) and d.group == "fast"]
    info = [d for d in got if isinstance(d, MapReading) and d.group == "info"]
    # 4 s at 0.25 s: 16 slots; a loaded machine may skip a few
    assert len(fast) >= 8, (len(fast), r.stderr)
    for d in fast:
        assert (d.values["a"], d.values["b"], d.values["c"]) == (100, 400, 700)
        assert d.values["missing"] is None
        assert d.states["missing"] == "unsupported"
    assert len(info) == 1, r.stderr
    assert info[0].values["serial"] == 1100
    # the refused register: learned once, not on each of the run's connections
    # (a request that raced the device's close may reach it twice)
    assert dev.asked[900] <= 4, dev.asked
    assert dev.asked[1000] == 1, dev.asked
    assert dev.asked[0] >= len(fast)
    with closing(sqlite3.connect(db)) as con:
        kinds = [k for (k,) in con.execute("SELECT kind FROM events ORDER BY id")]
        said = [m for (m,) in con.execute(
            "SELECT message FROM events WHERE kind = 'reconnect'")]
    # the first close is a loss (the device's way is not known yet), the second
    # teaches it: nothing more is said in the run
    assert [k for k in kinds if k not in ("connect", "reconnect", "skipped")] == [
        "connection"], kinds
    assert len(said) == 2, said
    assert "closes the connection after 1 reply: 1 request(s) per connection" in said[1]
    assert "failed poll" not in r.stderr


def test_read_and_watch_of_such_a_device(tmp_path: Path) -> None:
    """The blocking client sends a read again on a new connection when the
    device closed the last one after its reply: ``pymb read`` and ``pymb
    watch`` read every point, one request per connection."""
    (tmp_path / "one-shot.toml").write_text(MAP)
    dev = OneShot()
    where = f"127.0.0.1:{dev.gw.port}"
    try:
        r = run_pymb("read", "--map", str(tmp_path / "one-shot.toml"), "one-shot:1",
                     "--tcp", where, "--group", "fast", "--json")
        assert r.returncode == 0, r.stderr
        doc = json.loads(r.stdout)
        assert {k: doc["values"][k] for k in "abc"} == {"a": 100, "b": 400, "c": 700}
        assert doc["states"]["missing"] == "unsupported"
        r = run_pymb("watch", "--map", str(tmp_path / "one-shot.toml"), "one-shot:1",
                     "--tcp", where, "--group", "fast", "--count", "6", "--json")
        assert r.returncode == 0, r.stderr
        frames = [json.loads(ln) for ln in r.stdout.splitlines()]
        assert len(frames) == 6
        assert all(f["values"]["c"] == 700 for f in frames), frames
        assert len(dev.gw.accepted) >= 6  # a connection per request
        # the refused register is not asked again on each new connection (the
        # 7 reads' 28 connections); a request that raced the device's close
        # may reach it twice
        assert dev.asked[900] <= 4, dev.asked
    finally:
        dev.gw.close()


def test_a_write_is_not_sent_again() -> None:
    """A write that finds the connection closed is not sent again (the
    device may have done it): the caller is told."""
    dev = OneShot()
    try:
        with TcpClient("127.0.0.1", dev.gw.port, slave=1, timeout=2.0) as c:
            assert list(c.read_holding_registers(0, 2)) == [100, 101]
            assert list(c.read_holding_registers(300, 1)) == [400]  # sent again
            assert c.connections == 2
            with pytest.raises(ModbusConnectionError):
                c.write_register(5, 1)
            # once at most (it may reach the device as it closes): never again
            assert dev.asked.get(5, 0) <= 1
    finally:
        dev.gw.close()
