"""Sparkplug B DCMDs as a host of another vendor sends them, against ``pymb log
--mqtt-profile sparkplug`` in its own process, Debian's mosquitto and a scripted
RTU device on a real pseudo-terminal; DCMDs encoded, DBIRTH and DDATA decoded,
by pysparkplug's ``Payload`` (independent of pymb's encoder)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from mqtt_broker import Fleet, fleet, mosquitto, sparkplug_pb  # noqa: F401 (fixtures)
from sparkplug_host import Host, start
from write_mqtt import stop
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
