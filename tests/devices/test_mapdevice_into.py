"""``MapDevice.read_into``: the same read as ``read``, the values left in the
decoders' arrays (no dict), the same arrays every time, and a point the
device refuses reads NaN with the state ``unsupported``; and the map's reply
timeout given back to the line after a read. Against the scripted responder
that lacks some registers, over a real pseudo-terminal."""

from __future__ import annotations

import math

import pytest
from map_peers import RefusingPtyPeer

import pymb
from pymb import maps
from pymb.devices.mapdevice import MapDevice
from pymb.errors import ModbusTimeout
from pymb.maps import STATES

#: four points at 20..23; the peer lacks register 22 (g)
MAP = """schema = "pymb.map/1"
[device]
id = "testdev"
table = "holding"
[device.timing]
offline_retry = 3600
[groups]
slow = { interval = 10.0 }
""" + "".join(f'[[point]]\nname = "{n}"\naddress = {a}\ntype = "u16"\ngroup = "slow"\n'
              for n, a in (("e", 20), ("f", 21), ("g", 22), ("h", 23)))
HAVE = {"holding": {20, 21, 23}}


def test_read_into_leaves_read_s_values_in_the_decoders_arrays() -> None:
    with RefusingPtyPeer(HAVE) as peer, pymb.RtuClient(peer.port, 9600, timeout=1.0) as client:
        dev = MapDevice(client, maps.loads(MAP), 1)
        want = dev.read(group="slow")
        assert want == {"e": 140, "f": 147, "g": None, "h": 161}
        decoders = dev.read_into(group="slow")
        assert len(decoders) == 1
        d = decoders[0]
        b = d.buffers
        for name, value in want.items():
            slot = d.slot(name)
            if value is None:
                assert math.isnan(b.values[slot])
                assert STATES[b.states[slot]] == "unsupported"
            else:
                assert b.values[slot] == value
                assert STATES[b.states[slot]] == "value"
        again = dev.read_into(group="slow")
        assert again[0] is d
        assert again[0].buffers is b
        assert d.values() == {"e": 140, "f": 147, "g": None, "h": 161}
        assert dev.read_into("e", "h")[0].values() == {"e": 140, "h": 161}


TWO_TABLES = MAP + "".join(
    f'[[point]]\nname = "{n}"\naddress = {a}\ntype = "u16"\ntable = "input"\ngroup = "slow"\n'
    for n, a in (("x", 20), ("y", 21)))


@pytest.mark.parametrize("first", ["read_into", "read"])
def test_read_into_decodes_each_read_of_every_table_also_when_a_point_is_refused(
        first: str) -> None:
    # The first read_into meets the refusal itself (the fallback in the same
    # read), or after read() learnt it; a table of its own (input registers)
    # beside it. Each read decodes what it read: the peer's registers change.
    have = {"holding": {20, 21, 23}, "input": {20, 21}}
    with RefusingPtyPeer(have) as peer, pymb.RtuClient(peer.port, 9600, timeout=1.0) as client:
        dev = MapDevice(client, maps.loads(TWO_TABLES), 1)
        if first == "read":
            dev.read(group="slow")
        base = {"e": 140, "f": 147, "g": None, "h": 161, "x": 20, "y": 21}
        for k in range(3):
            holding, inputs = dev.read_into(group="slow")
            got = {**holding.values(), **inputs.values()}
            assert got == {n: None if v is None else v + k for n, v in base.items()}
            assert STATES[holding.buffers.states[holding.slot("g")]] == "unsupported"
            assert list(holding.buffers.registers)[:2] == [140 + k, 147 + k]
            for a in (20, 21, 23):
                peer.memory.holding[a] += 1
            for a in (20, 21):
                peer.memory.inputs[a] += 1


def test_the_map_s_reply_timeout_is_given_back_to_the_line_after_its_read() -> None:
    m = maps.loads(MAP.replace("offline_retry = 3600", "response_timeout = 0.1"))
    with RefusingPtyPeer(HAVE) as peer, pymb.RtuClient(peer.port, 9600, timeout=2.0) as client:
        delay = [0.4]
        peer.hook = lambda slave, pdu, normal: (
            None if normal is None else [(delay[0], peer.frame(slave, normal))])
        dev = MapDevice(client, m, 1)
        with pytest.raises(ModbusTimeout):
            dev.read("e")  # 0.1 s, the map's
        assert client.timeout == 2.0
        delay[0] = 0.3
        assert list(client.read_holding_registers(20, 1, slave=1)) == [140]  # 2 s again


def test_after_a_read_in_the_map_s_timeout_other_requests_get_the_line_s_own() -> None:
    m = maps.loads(MAP.replace("offline_retry = 3600", "response_timeout = 0.1"))
    with RefusingPtyPeer(HAVE) as peer, pymb.RtuClient(peer.port, 9600, timeout=2.0) as client:
        delay = [0.0]
        peer.hook = lambda slave, pdu, normal: (
            None if normal is None else [(delay[0], peer.frame(slave, normal))])
        dev = MapDevice(client, m, 1)
        for _ in range(2):  # the map's timeout stays on the line between its reads
            assert dev.read_into("e", "f")[0].values() == {"e": 140, "f": 147}
        delay[0] = 0.3  # longer than the map's 0.1 s, well within the line's 2 s
        assert client.raw_request(3, bytes([0, 20, 0, 1]), slave=1) == bytes([2, 0, 140])
        assert list(client.read_holding_registers(21, 1, slave=1)) == [147]
        with pytest.raises(ModbusTimeout):
            dev.read_into("e", "f")  # and the map's own again for its next read
        delay[0] = 0.0
        client.drain(0.5, 2.0)  # the late reply
        assert dev.read_into("e", "f")[0].values() == {"e": 140, "f": 147}
