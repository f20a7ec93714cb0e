"""Modbus TCP (MBAP) in front of the simulated bus, like an RTU gateway;
or, with ``rtu_framing``, RTU frames (address, PDU, CRC) on the TCP socket,
as a transparent serial server in "raw" mode passes them through (then the
RTU framing faults, ``bad_crc`` included, apply, and unit 0xFF is an
ordinary address).

The unit identifier is the slave address on the bus: unit 0 is a broadcast
(never answered), a unit no device has gets no answer (the request times
out, as behind a gateway that relays to a silent bus). Unit 0xFF ("not
used", what a TCP device answers to itself; mbpoll sends it) reaches the
only device of a one-device bus, unless a hub sits at address 255. All connections are
served by one thread, one request at a time, as a gateway serialises its
RTU line. The device's turnaround applies; with ``emulate_baud`` the RTU
wire time of request and reply is added. ``bad_crc`` has no meaning here (a
TCP frame has no CRC) and is never applied.
"""

from __future__ import annotations

import contextlib
import logging
import select
import socket
import struct
import time
from typing import Any

from pymb import _native
from pymb.sim.bus import IDLE_S, Bus, char_time, reply_gap, sleep_until
from pymb.sim.faults import Fault
from pymb.sim.rtu import frame_rtu
from pymb.sim.server import Server

__all__ = ["TcpServer", "frame_tcp"]

log = logging.getLogger("pymb.sim")

_MBAP = struct.Struct(">HHHB")  # transaction, protocol (0), length, unit
_MAX_PDU = 253  # [MB-AP] 4.1
_SEND_WAIT_S = 1.0
#: [MB-TCP] 4.4.1: unit 0xFF addresses a TCP device itself (mbpoll sends it)
_UNIT_NOT_USED = 0xFF


def frame_tcp(tid: int, unit: int, pdu: bytes, fault: Fault | None) -> bytes:
    """The MBAP reply with the framing faults applied."""
    if fault is not None and fault.kind == "wrong_address":
        unit = fault.to if fault.to is not None else unit % 247 + 1
    adu = _MBAP.pack(tid, 0, len(pdu) + 1, unit) + pdu
    if fault is None:
        return adu
    if fault.kind == "truncate":
        keep = fault.keep if fault.keep is not None else len(adu) // 2
        return adu[:min(keep, len(adu) - 1)]
    if fault.kind == "stray":
        return adu + (fault.extra or b"\x00")
    return adu


class TcpServer(Server):
    """Serves a bus as a Modbus TCP server on ``host``:``port`` (0: any free
    port); ``rtu_framing``: RTU frames over TCP instead of MBAP."""

    name = "tcp"

    def __init__(self, bus: Bus, host: str = "127.0.0.1", port: int = 0, *,
                 emulate_baud: int | None = None, rtu_framing: bool = False) -> None:
        super().__init__(bus)
        self.host = host
        self.port = port
        self.emulate_baud = emulate_baud
        self.rtu_framing = rtu_framing
        if rtu_framing:
            self.name = "rtu-over-tcp"
        self._listener: socket.socket | None = None
        self._clients: dict[socket.socket, bytearray] = {}

    def _open(self) -> None:
        family = socket.AF_INET6 if ":" in self.host else socket.AF_INET
        s = socket.socket(family, socket.SOCK_STREAM)
        try:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            s.bind((self.host, self.port))
            s.listen(8)
            s.setblocking(False)
        except OSError:
            s.close()
            raise
        self.port = s.getsockname()[1]  # keep the same port across replugs
        self._listener = s

    def _close(self) -> None:
        for c in list(self._clients):
            self._drop(c)
        if self._listener is not None:
            self._listener.close()
            self._listener = None

    def _drop(self, conn: socket.socket) -> None:
        self._clients.pop(conn, None)
        with contextlib.suppress(OSError):
            conn.close()

    def _serve_once(self, wake_fd: int) -> None:
        listener = self._listener
        assert listener is not None
        watched: list[Any] = [listener, wake_fd, *self._clients]
        r, _, _ = select.select(watched, [], [], IDLE_S)
        if not r:
            self.bus.idle()
            return
        if wake_fd in r:
            self._drain_wake()
            return
        for s in r:
            if s is listener:
                try:
                    conn, _ = listener.accept()
                except OSError:
                    continue
                conn.setblocking(False)
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                self._clients[conn] = bytearray()
            elif s in self._clients:
                self._receive(s)
            if self._listener is not listener:
                return  # unplugged by a fault

    def _receive(self, conn: socket.socket) -> None:
        try:
            data = conn.recv(4096)
        except BlockingIOError:
            return
        except OSError:
            data = b""
        if not data:
            self._drop(conn)
            return
        end = time.perf_counter()
        buf = self._clients[conn]
        buf += data
        if self.rtu_framing:
            self._receive_rtu(conn, buf, end)
            return
        while len(buf) >= _MBAP.size:
            tid, proto, length, unit = _MBAP.unpack_from(buf)
            if proto != 0 or not 2 <= length <= _MAX_PDU + 1:
                self.bus.stats.bad_frames += 1
                self._drop(conn)
                return
            if len(buf) < 6 + length:
                return
            pdu = bytes(buf[_MBAP.size:6 + length])
            del buf[:6 + length]
            self._dispatch(conn, tid, unit, pdu, end)
            if conn not in self._clients:
                return

    def _receive_rtu(self, conn: socket.socket, buf: bytearray, end: float) -> None:
        """RTU requests from the stream: each as long as its function code
        says; one whose length only silence tells is the rest of the segment."""
        while len(buf) >= 2:
            n = _native.rtu_request_length(buf)
            if n == -1:  # more bytes needed
                return
            if n < 0:
                n = len(buf)
            if len(buf) < n:
                return
            frame = bytes(buf[:n])
            del buf[:n]
            if len(frame) < 4 or not _native.rtu_crc_ok(frame):
                self.bus.stats.bad_frames += 1
                buf.clear()  # out of step: what follows cannot be trusted
                return
            self._dispatch(conn, 0, frame[0], frame[1:-2], end)
            if conn not in self._clients:
                return

    def _dispatch(self, conn: socket.socket, tid: int, unit: int, pdu: bytes,
                  end: float) -> None:
        t0 = time.perf_counter_ns()
        address = unit
        if not self.rtu_framing and unit == _UNIT_NOT_USED and len(self.bus.devices) == 1 \
                and self.bus.device(unit) is None:
            address = self.bus.devices[0].address
        out = self.bus.serve(address, pdu, tcp=not self.rtu_framing)
        if out is None:
            return
        if out.pdu is None:
            if out.fault is not None and out.fault.kind == "unplug":
                self._apply("unplug", out.fault.seconds)
            return
        reply = (frame_rtu(unit, out.pdu, out.fault) if self.rtu_framing
                 else frame_tcp(tid, unit, out.pdu, out.fault))
        self.bus.stats.served(time.perf_counter_ns() - t0)
        delay = out.delay
        baud = self.emulate_baud
        if baud:
            char = char_time(baud)
            delay = (len(pdu) + 3) * char + max(reply_gap(baud), delay) + (
                len(out.pdu) + 3) * char
        if not sleep_until(end + delay, self._stop):
            return
        self._send(conn, reply)

    def _send(self, conn: socket.socket, data: bytes) -> None:
        view = memoryview(data)
        deadline = time.perf_counter() + _SEND_WAIT_S
        while view:
            try:
                view = view[conn.send(view):]
            except BlockingIOError:
                left = deadline - time.perf_counter()
                if left <= 0:
                    self._drop(conn)
                    return
                select.select([], [conn], [], left)
            except OSError:
                self._drop(conn)
                return
