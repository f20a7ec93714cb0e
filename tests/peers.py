"""A small scripted Modbus peer for the client tests: a generic register and
coil memory behind a real pseudo-terminal (RTU) or a TCP socket on 127.0.0.1,
with a hook that can replace any reply by arbitrary bytes, a delay, or
silence. The device simulators (pymb.sim) model the real devices; this peer
exists to provoke the client's error paths exactly.
"""

from __future__ import annotations

import os
import select
import socket
import struct
import threading
import time
import tty
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field

from pymb import _native

# A hook gets (slave, request PDU, normal reply PDU or None) and returns a
# list of (delay_seconds, raw bytes to send) or None to send the normal reply.
Hook = Callable[[int, bytes, "bytes | None"], "list[tuple[float, bytes]] | None"]


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
        else:
            src = mem.holding if fc == 3 else mem.inputs
            data = struct.pack(f">{n}H", *src[addr:addr + n])
        return bytes((fc, len(data))) + data
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
        data = struct.pack(f">{rn}H", *mem.holding[ra:ra + rn])
        return bytes((0x17, len(data))) + data
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
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def reply_for(self, slave: int, pdu: bytes) -> list[tuple[float, bytes]]:
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

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5)


class PtyPeer(Peer):
    """RTU over a pseudo-terminal; ``port`` is the path a master opens."""

    def __init__(self, slaves: set[int] | None = None) -> None:
        super().__init__(slaves)
        self.master, self._slave_fd = os.openpty()
        tty.setraw(self.master)
        self.port = os.ttyname(self._slave_fd)
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def frame(self, slave: int, pdu: bytes) -> bytes:
        return _native.with_crc(bytes((slave,)) + pdu)

    def _run(self) -> None:
        buf = b""
        poller = select.poll()  # poll, not select: any descriptor number
        poller.register(self.master, select.POLLIN)
        while not self._stop.is_set():
            if not poller.poll(50):
                buf = b""  # silence ends any partial frame
                continue
            try:
                buf += os.read(self.master, 512)
            except OSError:
                return
            while len(buf) >= 2:
                n = _native.rtu_request_length(buf)
                if n < 0 or len(buf) < n:
                    break
                frame, buf = buf[:n], buf[n:]
                if not _native.rtu_crc_ok(frame):
                    continue
                for delay, data in self.reply_for(frame[0], frame[1:-2]):
                    if delay:
                        time.sleep(delay)
                    os.write(self.master, data)

    def stop(self) -> None:
        super().stop()
        for fd in (self.master, self._slave_fd):
            with suppress(OSError):
                os.close(fd)


class TcpPeer(Peer):
    """Modbus TCP on 127.0.0.1; ``address`` is (host, port)."""

    def __init__(self, slaves: set[int] | None = None) -> None:
        super().__init__(slaves)
        self._sock = socket.create_server(("127.0.0.1", 0))
        self._sock.settimeout(0.05)
        self.address = self._sock.getsockname()
        self._tid = 0
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def frame(self, slave: int, pdu: bytes) -> bytes:
        return struct.pack(">HHHB", self._tid, 0, len(pdu) + 1, slave) + pdu

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self._sock.accept()
            except (TimeoutError, OSError):
                continue
            with conn:
                conn.settimeout(0.05)
                buf = b""
                while not self._stop.is_set():
                    try:
                        data = conn.recv(512)
                    except TimeoutError:
                        continue
                    except OSError:
                        break
                    if not data:
                        break
                    buf += data
                    while len(buf) >= 7:
                        tid, _, length = struct.unpack(">HHH", buf[:6])
                        if len(buf) < 6 + length:
                            break
                        adu, buf = buf[:6 + length], buf[6 + length:]
                        self._tid = tid
                        for delay, out in self.reply_for(adu[6], adu[7:]):
                            if delay:
                                time.sleep(delay)
                            conn.sendall(out)

    def stop(self) -> None:
        super().stop()
        self._sock.close()


@contextmanager
def pty_peer(slaves: set[int] | None = None) -> Iterator[PtyPeer]:
    """A running PtyPeer, stopped on exit."""
    peer = PtyPeer(slaves)
    try:
        yield peer
    finally:
        peer.stop()


@contextmanager
def tcp_peer(slaves: set[int] | None = None) -> Iterator[TcpPeer]:
    """A running TcpPeer, stopped on exit."""
    peer = TcpPeer(slaves)
    try:
        yield peer
    finally:
        peer.stop()
