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
RTU line. Given ``ports``, the same bus answers on each of them (a 0 is any
free port), as many TCP devices on one network would, for tests and benchmarks
of a master that polls them all; one thread serves them all through one
selector. The device's turnaround applies; with ``emulate_baud`` the RTU
wire time of request and reply is added. ``bad_crc`` has no meaning here (a
TCP frame has no CRC) and is never applied.
"""

from __future__ import annotations

import contextlib
import logging
import selectors
import socket
import time

from pymb import _native
from pymb._native.serve import BadFrame, mbap_frame, take_frames
from pymb.errors import InvalidArgument
from pymb.sim.bus import IDLE_S, Bus, char_time, reply_gap, sleep_until
from pymb.sim.faults import Fault, framed
from pymb.sim.rtu import frame_rtu
from pymb.sim.server import SimServer, write_all

__all__ = ["MAX_PORTS", "TcpServer", "format_ports", "frame_tcp", "parse_ports"]

log = logging.getLogger("pymb.sim")

_SEND_WAIT_S = 1.0
#: [MB-TCP] 4.4.1: unit 0xFF addresses a TCP device itself (mbpoll sends it)
_UNIT_NOT_USED = 0xFF
#: the most ports one simulator serves (each a listener and a connection: 2 descriptors)
MAX_PORTS = 1000


def parse_ports(text: str, what: str = "--tcp") -> list[int]:
    """``PORT``, ``FIRST-LAST`` or ``P1,P2,...`` as a list of ports."""
    ports: list[int] = []
    try:
        for part in text.split(","):
            first, dash, last = part.strip().partition("-")
            a = int(first)
            b = int(last) if dash else a
            if not (0 <= a <= 65535 and 0 <= b <= 65535 and a <= b):
                raise ValueError(part)
            ports.extend(range(a, b + 1))
    except ValueError:
        raise InvalidArgument(f"{what}: bad port or port range {text!r} "
                              "(PORT, FIRST-LAST or P1,P2,... in 0..65535)") from None
    if len(ports) > MAX_PORTS:
        raise InvalidArgument(f"{what}: {len(ports)} ports; at most {MAX_PORTS}")
    return ports


def format_ports(ports: list[int]) -> str:
    """``FIRST-LAST`` when ``ports`` run on by one, else ``P1,P2,...``."""
    if len(ports) > 1 and ports == list(range(ports[0], ports[0] + len(ports))):
        return f"{ports[0]}-{ports[-1]}"
    return ",".join(str(p) for p in ports)


def frame_tcp(tid: int, unit: int, pdu: bytes, fault: Fault | None) -> bytes:
    """The MBAP reply with the framing faults applied."""
    return framed(lambda u: mbap_frame(tid, u, pdu), unit, fault)


class TcpServer(SimServer):
    """Serves a bus as a Modbus TCP server on ``host``:``port`` (0: any free
    port); ``rtu_framing``: RTU frames over TCP instead of MBAP."""

    name = "tcp"

    def __init__(self, bus: Bus, host: str = "127.0.0.1", port: int = 0, *,
                 emulate_baud: int | None = None, rtu_framing: bool = False,
                 ports: list[int] | None = None) -> None:
        super().__init__(bus)
        if ports is not None and not 1 <= len(ports) <= MAX_PORTS:
            raise InvalidArgument(f"give 1..{MAX_PORTS} ports, got {len(ports)}")
        self.host = host
        self.port = port
        #: the ports served (0: picked by the system, then kept across replugs)
        self.ports = list(ports) if ports is not None else [port]
        self.emulate_baud = emulate_baud
        self.rtu_framing = rtu_framing
        if rtu_framing:
            self.name = "rtu-over-tcp"
        self._listeners: list[socket.socket] = []
        self._clients: dict[socket.socket, bytearray] = {}
        self._selector: selectors.BaseSelector | None = None
        self._wake_fd = -1

    def _open(self) -> None:
        family = socket.AF_INET6 if ":" in self.host else socket.AF_INET
        sel = selectors.DefaultSelector()
        listeners: list[socket.socket] = []
        try:
            for i, port in enumerate(self.ports):
                s = socket.socket(family, socket.SOCK_STREAM)
                listeners.append(s)
                s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                s.bind((self.host, port))
                s.listen(8)
                s.setblocking(False)
                self.ports[i] = s.getsockname()[1]  # the same ports across replugs
                sel.register(s, selectors.EVENT_READ, "listener")
        except OSError:
            for s in listeners:
                s.close()
            sel.close()
            raise
        self.port = self.ports[0]
        self._listeners = listeners
        self._selector = sel
        self._wake_fd = -1

    def _close(self) -> None:
        for c in list(self._clients):
            self._drop(c)
        for s in self._listeners:
            s.close()
        self._listeners = []
        if self._selector is not None:
            self._selector.close()
            self._selector = None

    def _drop(self, conn: socket.socket) -> None:
        if self._clients.pop(conn, None) is not None and self._selector is not None:
            with contextlib.suppress(KeyError, ValueError, OSError):
                self._selector.unregister(conn)
        with contextlib.suppress(OSError):
            conn.close()

    def _serve_once(self, wake_fd: int) -> None:
        sel = self._selector
        assert sel is not None
        if self._wake_fd != wake_fd:
            sel.register(wake_fd, selectors.EVENT_READ, "wake")
            self._wake_fd = wake_fd
        events = sel.select(IDLE_S)
        if not events:
            self.bus.idle()
            return
        for key, _ in events:
            if key.data == "wake":
                self._drain_wake()
                return
        for key, _ in events:
            s = key.fileobj
            assert isinstance(s, socket.socket)
            if key.data == "listener":
                try:
                    conn, _ = s.accept()
                except OSError:
                    continue
                conn.setblocking(False)
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                self._clients[conn] = bytearray()
                sel.register(conn, selectors.EVENT_READ, "client")
            elif s in self._clients:
                self._receive(s)
            if self._selector is not sel:
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
        bad = False
        try:
            frames = take_frames(buf)  # the C core's MBAP length rule, as pymb serve's
        except BadFrame as e:  # the requests before the bad header are answered first
            frames, bad = e.frames, True
        for frame in frames:
            self._dispatch(conn, frame[0] << 8 | frame[1], frame[6], frame[7:], end)
            if conn not in self._clients:
                return
        if bad:
            self.bus.stats.bad_frames += 1
            self._drop(conn)

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
        try:
            reply = (frame_rtu(unit, out.pdu, out.fault) if self.rtu_framing
                     else frame_tcp(tid, unit, out.pdu, out.fault))
        except ValueError as e:  # a handle's reply that no MBAP frame holds
            log.warning("%s at address %d: %s: not sent", out.device.kind, address, e)
            return
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
        if not write_all(conn.fileno(), data, _SEND_WAIT_S):
            self._drop(conn)
