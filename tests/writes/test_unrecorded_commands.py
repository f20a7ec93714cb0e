"""A write command the logger cannot put on record is not carried out: its
database turned read-only under it (ext4 on a loop device, its error handler
triggered, as a failing card does), a plain command is answered ``ok: false``,
reason ``device``, saying it was not recorded and nothing was written, and a
Sparkplug DCMD is answered with the current values; the device gets no write.
Real processes: ``pymb log``, Debian's mosquitto, a paho commander or
pysparkplug's payloads, a scripted RTU device on a pseudo-terminal. Needs root
(tests/disks.py)."""

from __future__ import annotations

import subprocess
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from mqtt_broker import Fleet, fleet, mosquitto, sparkplug_pb  # noqa: F401 (fixtures)
from write_mqtt import Commander, start, writes_sent
from write_peers import WRITE_MAP, FreezingPtyPeer

pytest.register_assert_rewrite("disks")
from disks import LoopDisk, need_root  # noqa: E402
from sparkplug_host import DOUBLE, Host  # noqa: E402
from sparkplug_host import start as start_sparkplug  # noqa: E402

paho = pytest.importorskip("paho.mqtt.client")

#: polled once at the start: after the disk fails nothing but the command writes
SLOW = ("--interval", "60")


@pytest.fixture
def peer() -> Iterator[FreezingPtyPeer]:
    with FreezingPtyPeer() as p:
        p.memory.holding[10] = 5000  # setpoint_hz 50.00
        p.memory.holding[12] = 0
        yield p


@pytest.fixture
def card(tmp_path: Path) -> Iterator[LoopDisk]:
    need_root()
    disk = LoopDisk(tmp_path / "card.img", tmp_path / "card", size_mb=32,
                    options="errors=remount-ro")
    try:
        yield disk
    finally:
        disk.umount()


def _map(tmp_path: Path) -> Path:
    path = tmp_path / "wdev.toml"
    path.write_text(WRITE_MAP.format(device="", limits="", budget=""))
    return path


def _ended(proc: subprocess.Popen[str]) -> str:
    """Stop the logger; it ends saying the database could not be written."""
    proc.terminate()
    _, err = proc.communicate(timeout=60)
    assert "Traceback" not in err, err
    return err


def test_a_plain_command_not_recorded_is_refused_and_not_written(
        fleet: Fleet, peer: FreezingPtyPeer, card: LoopDisk,  # noqa: F811
        tmp_path: Path) -> None:
    broker = fleet.broker()
    proc = start(fleet, broker, peer, _map(tmp_path), card.mountpoint / "log.sqlite",
                 "--port", peer.port, "--baud", "19200", *SLOW)
    cmd = Commander(fleet, broker)
    try:
        r = cmd.send({"id": "c-1", "values": {"setpoint_hz": 49.5}})
        assert r["ok"] is True, r
        sent = len(writes_sent(peer))
        card.fail()  # read-only at once
        r = cmd.send({"id": "c-2", "values": {"setpoint_hz": 48.0}})
        assert (r["ok"], r["reason"], r["values"]) == (False, "device", {}), r
        assert r["error"].startswith("not executed: it could not be put on record (cannot "
                                     "write to "), r
        assert r["error"].endswith("; nothing was written"), r
        assert len(writes_sent(peer)) == sent
        assert peer.memory.holding[10] == 4950
    finally:
        cmd.close()
    err = _ended(proc)
    assert "write command c-2 for psu-a not executed: it could not be put on record" in err


def test_a_dcmd_not_recorded_is_answered_with_the_current_values(
        fleet: Fleet, peer: FreezingPtyPeer, card: LoopDisk,  # noqa: F811
        tmp_path: Path, sparkplug_pb: Any) -> None:  # noqa: F811
    broker = fleet.broker()
    host = Host(fleet, broker, sparkplug_pb)
    proc = start_sparkplug(fleet, broker, peer, _map(tmp_path),
                           card.mountpoint / "log.sqlite", "--port", peer.port,
                           "--baud", "19200", *SLOW)
    try:
        try:
            birth = host.birth()
        except AssertionError:
            proc.kill()
            raise AssertionError(proc.communicate()[1]) from None
        aliases = {m.name: m.alias for m in birth.metrics}
        n = len(host.sub.snapshot())
        host.dcmd(("setpoint_hz", DOUBLE, 49.5))
        assert host.answer(n, aliases) == {"setpoint_hz": 49.5}
        sent = len(writes_sent(peer))
        card.fail()
        n = len(host.sub.snapshot())
        host.dcmd(("setpoint_hz", DOUBLE, 48.0))
        answer = host.answer(n, aliases)
        assert set(answer) == {"setpoint_hz"}
        assert answer["setpoint_hz"] != 48.0  # the value last sampled, not the command's
        assert len(writes_sent(peer)) == sent
        assert peer.memory.holding[10] == 4950
    finally:
        host.close()
    err = _ended(proc)
    assert "not executed: it could not be put on record" in err
