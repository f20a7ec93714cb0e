"""``MapDevice.read_into``: the same read as ``read``, the values left in the
decoders' arrays (no dict), the same arrays every time, and a point the
device refuses reads NaN with the state ``unsupported``; against the
scripted responder that lacks some registers, over a real pseudo-terminal."""

from __future__ import annotations

import math

from map_peers import RefusingPtyPeer

import pymb
from pymb import maps
from pymb.devices.mapdevice import MapDevice
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
