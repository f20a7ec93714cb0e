"""Writes of a ``scale_from`` point (the device's scale factor read first,
never guessed) and of a masked value (the register's other bits kept),
against a scripted Modbus TCP responder."""

from __future__ import annotations

import struct

import pytest
from peers import TcpPeer

import pymb
from pymb import InvalidArgument, maps
from pymb.devices.mapdevice import MapDevice

INVERTER = '''schema = "pymb.map/1"
[device]
id = "inv"
[[point]]
name = "WMaxLimPct"
address = 40200
type = "u16"
scale_from = "WMaxLimPct_SF"
access = "rw"
valid = [0, 100]
[[point]]
name = "WMaxLimPct_SF"
address = 40210
type = "sunssf"
[[point]]
name = "control"
address = 40220
type = "u16"
mask = 0x0006
access = "rw"
'''


def test_a_scaled_write_uses_the_devices_scale_factor_and_a_masked_one_keeps_bits() -> None:
    m = maps.loads(INVERTER)
    peer = TcpPeer()
    mem = peer.memory.holding
    mem[40200], mem[40210], mem[40220] = 0, (-2) & 0xFFFF, 0xFFF9
    with peer, pymb.TcpClient("127.0.0.1", peer.port, timeout=2.0) as client:
        dev = MapDevice(client, m, 1)
        assert dev.write("WMaxLimPct", 87.5) == 87.5
        assert mem[40200] == 8750  # 87.5 / 10^-2
        mem[40210] = 0xFFFF  # the device now says SF = -1
        assert dev.write("WMaxLimPct", 87.5) == 87.5
        assert mem[40200] == 875
        assert dev.read("WMaxLimPct") == {"WMaxLimPct": 87.5, "WMaxLimPct_SF": -1}
        mem[40210] = 0x8000  # not implemented: nothing is written
        with pytest.raises(InvalidArgument, match="scale factor"):
            dev.write("WMaxLimPct", 50)
        assert mem[40200] == 875
        writes = [pdu for _, pdu in peer.requests if pdu[0] in (6, 16)]
        assert len(writes) == 2
        assert dev.write("control", 0x0004) == 0x0004
        assert mem[40220] == 0xFFF9 | 0x0004  # the bits outside the mask as they were
        with pytest.raises(InvalidArgument, match="outside its mask"):
            dev.write("control", 0x0001)
        reads = [struct.unpack(">HH", pdu[1:5]) for _, pdu in peer.requests if pdu[0] == 3]
        assert (40210, 1) in reads
