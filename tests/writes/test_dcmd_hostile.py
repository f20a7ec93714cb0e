"""Sparkplug B DCMDs as a host of another vendor sends them, against ``pymb log
--mqtt-profile sparkplug`` in its own process, Debian's mosquitto and a scripted
RTU device on a real pseudo-terminal; DCMDs encoded, DBIRTH and DDATA decoded,
by pysparkplug's ``Payload`` (independent of pymb's encoder)."""

from __future__ import annotations

import os
import signal
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from collectkit import publish
from conftest import wait_until
from mqtt_broker import Fleet, fleet, mosquitto, sparkplug_pb  # noqa: F401 (fixtures)
from sparkplug_host import DEVICE, GROUP, NODE, Host, start
from write_mqtt import rows, stop, writes_sent
from write_peers import WRITE_MAP, FreezingPtyPeer

INT16 = 2

#: the write tests' map with its zone temperatures in whole degrees, signed
SIGNED_MAP = WRITE_MAP.replace('scale = 0.1\nunit = "°C"\naccess = "rw"\nvalid = [5.0, 30.0]',
                               'unit = "°C"\naccess = "rw"\nvalid = [-30, 30]')


@pytest.fixture
def peer() -> Iterator[FreezingPtyPeer]:
    with FreezingPtyPeer() as p:
        for c in range(4):
            p.memory.holding[40 + c] = 20
        yield p


def test_a_dcmd_without_datatypes_is_read_as_the_dbirth_declared(
        fleet: Fleet, peer: FreezingPtyPeer, tmp_path: Path,  # noqa: F811
        sparkplug_pb: Any) -> None:  # noqa: F811
    """Sparkplug 3.0: the datatype should not be included in a DCMD's metrics. A
    negative Int16 sent so (its two's complement in the uint32 ``int_value``) is
    written as the DBIRTH's datatype reads it, by alias and by name."""
    assert SIGNED_MAP != WRITE_MAP
    map_file = tmp_path / "wdev.toml"
    map_file.write_text(SIGNED_MAP.format(device="", limits="", budget=""))
    broker = fleet.broker()
    host = Host(fleet, broker, sparkplug_pb)
    proc = start(fleet, broker, peer, map_file, tmp_path / "log.sqlite")
    try:
        birth = host.birth()
        zone = next(m for m in birth.metrics if m.name == "channel 002/zone_c")
        assert zone.datatype == INT16
        aliases = {m.name: m.alias for m in birth.metrics}
        for key, value in ((zone.alias, -12), ("channel 002/zone_c", -7)):
            p = sparkplug_pb()
            host.stamp += 1
            p.timestamp = host.stamp
            m = p.metrics.add()
            if isinstance(key, str):
                m.name = key
            else:
                m.alias = key
            m.int_value = value & 0xFFFFFFFF  # no datatype
            n = len(host.sub.snapshot())
            host.send(p.SerializeToString())
            got = host.answer(n, aliases)
            # an Int16 in a uint32: its two's complement in 16 or in 32 bits
            assert {k: ((v & 0xFFFF) ^ 0x8000) - 0x8000 for k, v in got.items()} == {
                "channel 002/zone_c": value}, got
            assert peer.memory.holding[41] == value & 0xFFFF
    finally:
        host.close()
    stop(proc)


def test_a_retained_dcmd_from_before_the_node_is_not_executed(
        fleet: Fleet, peer: FreezingPtyPeer, tmp_path: Path,  # noqa: F811
        sparkplug_pb: Any) -> None:  # noqa: F811
    """Sparkplug: a DCMD is published with retain false. One the broker held
    retained from before the node subscribed (here: published while the node
    was away, a broker restart) is refused and recorded; nothing is
    written."""
    map_file = tmp_path / "wdev.toml"
    map_file.write_text(SIGNED_MAP.format(device="", limits="", budget=""))
    broker = fleet.broker()
    host = Host(fleet, broker, sparkplug_pb)
    db = tmp_path / "log.sqlite"
    proc = start(fleet, broker, peer, map_file, db)
    try:
        host.birth()
    finally:
        host.close()
    p = sparkplug_pb()
    p.timestamp, p.seq = 1796299201234, 0
    m = p.metrics.add()
    m.name, m.datatype, m.int_value = "channel 002/zone_c", INT16, 25
    os.kill(proc.pid, signal.SIGSTOP)  # the node reconnects once the DCMD is retained
    try:
        broker.stop()
        broker.start()
        publish(broker.port, [(f"spBv1.0/{GROUP}/DCMD/{NODE}/{DEVICE}",
                               p.SerializeToString())], retain=True)
    finally:
        os.kill(proc.pid, signal.SIGCONT)
    wait_until(lambda: rows(db), "the DCMD on record", 60)
    time.sleep(1.0)  # (a write would follow its record at once)
    err = stop(proc)
    assert not writes_sent(peer)
    assert peer.memory.holding[41] == 20
    assert [(r[0], r[3], r[7], r[8]) for r in rows(db)] == [
        ("sparkplug", "zone_c_2", 0, "invalid")]
    assert "a retained DCMD, held by the broker from before the node subscribed" in err, err
