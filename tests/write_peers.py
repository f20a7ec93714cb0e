"""Scripted peers for the write tests: the generic peer of tests/peers.py
(every request logged in ``requests``) that can acknowledge a write without
applying it: ``frozen`` holding registers and ``frozen_coils`` keep their
value whatever is written, and the write is answered as done (what an
EEPROM-backed or locked register does). Also the map the write tests share."""

from __future__ import annotations

from peerkit import Reply
from peers import Peer, PtyPeer, TcpPeer

from pymb import maps

WRITE_MAP = """schema = "pymb.map/1"
[device]
id = "wdev"
default_address = 1
table = "holding"
{device}

[device.limits]
{limits}

[[point]]
name = "setpoint_hz"
address = 10
type = "u16"
scale = 0.01
unit = "Hz"
access = "rw"
valid = [45.0, 65.0]
{budget}

[[point]]
name = "power_limit_pct"
address = 11
type = "u16"
unit = "%"
access = "rw"
valid = [0, 100]

[[point]]
name = "mode"
address = 12
type = "u16"
access = "rw"
values = {{ 0 = "stop", 1 = "run" }}

[[point]]
name = "target_w"
address = 14
type = "f32"
unit = "W"
access = "rw"

[[point]]
name = "status"
address = 20
type = "u16"
access = "rw"

[[point]]
name = "firmware"
address = 25
type = "u16"

[[point]]
name = "relay_2"
address = 20
type = "bit"
bit = 2
access = "rw"

[[point]]
name = "relay_5"
address = 20
type = "bit"
bit = 5
access = "rw"

[[point]]
name = "level"
address = 21
type = "u8_lo"
access = "rw"

[[point]]
name = "reset"
address = 30
type = "u16"
access = "w"

[[block]]
name = "zone_c"
first = 40
count = 4
type = "i16"
scale = 0.1
unit = "°C"
access = "rw"
valid = [5.0, 30.0]

[[point]]
name = "pump_on"
table = "coil"
address = 5
access = "rw"

[[point]]
name = "fan_on"
table = "coil"
address = 6
access = "rw"

[[point]]
name = "voltage_v"
table = "input"
address = 0
type = "u16"
"""


def write_map(device: str = "", limits: str = "", budget: str = "") -> maps.Map:
    """The write tests' map, with extra ``[device]``/``[device.limits]`` lines
    and a ``max_writes_per_hour`` line for ``setpoint_hz``."""
    return maps.loads(WRITE_MAP.format(device=device, limits=limits, budget=budget),
                      source="wdev.toml")


class Freezing(Peer):
    """A peer whose ``frozen`` registers (``frozen_coils``) acknowledge writes
    and keep their value."""

    frozen: set[int]
    frozen_coils: set[int]

    def reply_for(self, slave: int, pdu: bytes) -> Reply:
        mem = self.memory
        held = {a: mem.holding[a] for a in self.frozen}
        coils = {a: mem.coils[a] for a in self.frozen_coils}
        try:
            return super().reply_for(slave, pdu)
        finally:
            for a, v in held.items():
                mem.holding[a] = v
            for a, c in coils.items():
                mem.coils[a] = c

    def functions(self) -> list[int]:
        """The function code of every request received, in order."""
        return [pdu[0] for _, pdu in self.requests]


class FreezingTcpPeer(Freezing, TcpPeer):
    """Modbus TCP on 127.0.0.1."""

    def __init__(self, slaves: set[int] | None = None) -> None:
        TcpPeer.__init__(self, slaves)
        self.frozen, self.frozen_coils = set(), set()


class FreezingPtyPeer(Freezing, PtyPeer):
    """RTU on a pseudo-terminal."""

    def __init__(self, slaves: set[int] | None = None) -> None:
        PtyPeer.__init__(self, slaves)
        self.frozen, self.frozen_coils = set(), set()
