"""A small scripted Modbus peer for the client tests: a generic register and
coil memory behind a real pseudo-terminal (RTU) or a TCP socket on 127.0.0.1
(tests/peerkit.py), with a hook that can replace any reply by arbitrary bytes,
a delay, or silence. The device simulators (pymb.sim) model the real devices;
this peer exists to provoke the client's error paths exactly. Its frames and
CRC are the specification's (peerkit); only where an RTU request ends is
asked of pymb (``_native.rtu_request_length``).
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass, field

from peerkit import PtyPeerBase, Reply, TcpPeerBase, mbap, registers, rtu, rtu_crc_ok

from pymb import _native

# A hook gets (slave, request PDU, normal reply PDU or None) and returns a
# list of (delay_seconds, raw bytes to send) or None to send the normal reply.
Hook = Callable[[int, bytes, "bytes | None"], "Reply | None"]


@dataclass
class Memory:
    """What the peer serves: 65536 holding/input registers, coils, inputs."""

    holding: list[int] = field(default_factory=lambda: [(i * 7) & 0xFFFF for i in range(65536)])
    inputs: list[int] = field(default_factory=lambda: [i & 0xFFFF for i in range(65536)])
    coils: list[int] = field(default_factory=lambda: [i % 3 == 0 for i in range(65536)])
    discrete: list[int] = field(default_factory=lambda: [i % 2 for i in range(65536)])


def _bits(values: list[int]) -> bytes:
    out = bytearray((len(values) + 7) // 8)
    for i, v in enumerate(values):
        if v:
            out[i // 8] |= 1 << (i % 8)
    return bytes(out)


def handle(mem: Memory, pdu: bytes) -> bytes:
    """Answer a request PDU as a plain Modbus server would."""
    fc = pdu[0]

    def exc(code: int) -> bytes:
        return bytes((fc | 0x80, code))

    if fc in (1, 2, 3, 4):
        addr, n = struct.unpack(">HH", pdu[1:5])
        limit = 2000 if fc <= 2 else 125
        if not 1 <= n <= limit:
            return exc(3)
        if addr + n > 65536 or addr >= 60000:
            return exc(2)
        if fc <= 2:
            src = mem.coils if fc == 1 else mem.discrete
            data = _bits(src[addr:addr + n])
            return bytes((fc, len(data))) + data
        src = mem.holding if fc == 3 else mem.inputs
        return bytes((fc,)) + registers(src[addr:addr + n])
    if fc == 5:
        addr, v = struct.unpack(">HH", pdu[1:5])
        if v not in (0, 0xFF00):
            return exc(3)
        mem.coils[addr] = int(v == 0xFF00)
        return pdu
    if fc == 6:
        addr, v = struct.unpack(">HH", pdu[1:5])
        if addr >= 60000:
            return exc(2)
        mem.holding[addr] = v
        return pdu
    if fc == 7:
        return bytes((7, 0x5A))
    if fc == 15:
        addr, n, _ = struct.unpack(">HHB", pdu[1:6])
        for i in range(n):
            mem.coils[addr + i] = (pdu[6 + i // 8] >> (i % 8)) & 1
        return pdu[:5]
    if fc == 16:
        addr, n, _ = struct.unpack(">HHB", pdu[1:6])
        mem.holding[addr:addr + n] = struct.unpack(f">{n}H", pdu[6:6 + 2 * n])
        return pdu[:5]
    if fc == 0x11:
        ident = b"\x2a\xffpymb-peer"
        return bytes((0x11, len(ident))) + ident
    if fc == 0x16:
        addr, andm, orm = struct.unpack(">HHH", pdu[1:7])
        mem.holding[addr] = (mem.holding[addr] & andm) | (orm & ~andm & 0xFFFF)
        return pdu
    if fc == 0x17:
        ra, rn, wa, wn, _ = struct.unpack(">HHHHB", pdu[1:10])
        mem.holding[wa:wa + wn] = struct.unpack(f">{wn}H", pdu[10:10 + 2 * wn])
        return bytes((0x17,)) + registers(mem.holding[ra:ra + rn])
    return exc(1)


class Peer:
    """Serves ``slaves`` from ``memory``; ``hook`` may rewrite any reply.

    ``requests`` records every request frame received (address + PDU).
    """

    def __init__(self, slaves: set[int] | None = None) -> None:
        self.memory = Memory()
        self.slaves = slaves
        self.hook: Hook | None = None
        self.requests: list[tuple[int, bytes]] = []

    def reply_for(self, slave: int, pdu: bytes) -> Reply:
        self.requests.append((slave, pdu))
        normal: bytes | None = None
        if self.slaves is None or slave in self.slaves:
            normal = handle(self.memory, pdu)
        if self.hook is not None:
            scripted = self.hook(slave, pdu, normal)
            if scripted is not None:
                return scripted
        return [] if normal is None else [(0.0, self.frame(slave, normal))]

    def frame(self, slave: int, pdu: bytes) -> bytes:
        raise NotImplementedError


class PtyPeer(Peer, PtyPeerBase):
    """RTU over a pseudo-terminal; ``port`` is the path a master opens."""

    def __init__(self, slaves: set[int] | None = None) -> None:
        Peer.__init__(self, slaves)
        PtyPeerBase.__init__(self)

    def frame(self, slave: int, pdu: bytes) -> bytes:
        return rtu(bytes((slave,)) + pdu)

    def received(self, buf: bytes) -> bytes:
        while len(buf) >= 2:
            n = _native.rtu_request_length(buf)
            if n < 0 or len(buf) < n:
                break
            frame, buf = buf[:n], buf[n:]
            if rtu_crc_ok(frame):
                self.send(self.reply_for(frame[0], frame[1:-2]))
        return buf


class TcpPeer(Peer, TcpPeerBase):
    """Modbus TCP on 127.0.0.1; ``address`` is (host, port)."""

    def __init__(self, slaves: set[int] | None = None) -> None:
        Peer.__init__(self, slaves)
        TcpPeerBase.__init__(self)
        self._tid = 0

    def frame(self, slave: int, pdu: bytes) -> bytes:
        return mbap(self._tid, slave, pdu)

    def answer(self, request: bytes) -> Reply:
        (self._tid,) = struct.unpack(">H", request[:2])
        return self.reply_for(request[6], request[7:])
