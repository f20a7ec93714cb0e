"""``pymb serve`` in front of a device that takes one request a connection
(it closes, or resets, the connection after each reply, as some Modbus TCP
devices and transparent serial servers do): every read is answered, sent
again on a new connection when it found the old one closed, as pymb's
clients send a read again; a write never is sent twice."""

from __future__ import annotations

import socket
import struct
import time

from peerkit import TcpPeerBase, mbap, registers, rtu, split_mbap
from servekit import RawClient, Served, read_pdu, words


class OneShot(TcpPeerBase):
    """Answers the first request of each connection with the register asked
    for (value = its address) and closes the connection; anything else sent
    on it is never read, so the close is a reset. ``rtu_frames``: RTU frames
    on TCP (a transparent serial server), else Modbus TCP."""

    def __init__(self, *, rtu_frames: bool = False) -> None:
        super().__init__()
        self.rtu_frames = rtu_frames
        self.requests: list[bytes] = []  #: the first request of each connection
        self.connections = 0

    def _serve(self, conn: socket.socket) -> None:
        self.connections += 1
        buf = b""
        while not self._stop.is_set():
            try:
                data = conn.recv(1024)
            except TimeoutError:
                continue
            except OSError:
                return
            if not data:
                return
            buf += data
            if self.rtu_frames:
                if len(buf) < 8:
                    continue
                req = buf[:8]
                self.requests.append(req)
                pdu = req[1:6] if req[1] == 6 else bytes((3,)) + registers([req[2] << 8 | req[3]])
                conn.sendall(rtu(req[:1] + pdu))
                return
            frames, buf = split_mbap(buf)
            if frames:
                req = frames[0]
                self.requests.append(req)
                tid, unit, pdu = req[0] << 8 | req[1], req[6], req[7:]
                reply = pdu if pdu[0] == 6 else bytes((3,)) + registers([pdu[1] << 8 | pdu[2]])
                conn.sendall(mbap(tid, unit, reply))
                return


def test_reads_through_serve_to_a_modbus_tcp_device_that_closes_after_each_reply() -> None:
    with OneShot() as device, Served("--tcp", f"127.0.0.1:{device.port}",
                                     "--timeout", "2") as s:
        c = RawClient(s.port)
        assert [words(c.ask(i, 1, read_pdu(i, 1))) for i in range(5)] == [[i] for i in range(5)]
        # three clients, three reads each sent at once: eight may be in flight
        # upstream; the device answers one a connection, so serve falls to one
        # at a time and sends again what it had sent on a closed connection
        clients = [RawClient(s.port) for _ in range(3)]
        for k, cc in enumerate(clients):
            cc.send(b"".join(struct.pack(">HHHBBHH", j, 0, 6, 1, 3, 10 * k + j, 1)
                             for j in range(3)))
        got = [[words(cc.reply()[2]) for _ in range(3)] for cc in clients]
        assert got == [[[10 * k + j] for j in range(3)] for k in range(3)]
        for cc in (c, *clients):
            cc.close()
        assert s.stop() == 0
    # its one reply, or a reset that lost it (more requests were unread)
    assert any(("closed the connection after one reply" in line
                or "reset the connection before any reply was read" in line) and
               "one transaction at a time from now" in line for line in s.stderr_lines), \
        s.stderr_lines
    assert not any("0x0A" in line for line in s.stderr_lines), s.stderr_lines


def test_through_rtu_over_tcp_a_read_is_sent_again_and_a_write_never() -> None:
    with OneShot(rtu_frames=True) as device, Served("--rtu-over-tcp",
                                                    f"127.0.0.1:{device.port}",
                                                    "--timeout", "2") as s:
        c = RawClient(s.port)
        assert [words(c.ask(i, 1, read_pdu(i, 1))) for i in range(4)] == [[i] for i in range(4)]
        # the write finds the connection the last read's reply closed: the
        # device may have taken it, so it is answered 0x0A, not sent again
        assert c.ask(9, 1, struct.pack(">BHH", 6, 1, 7)) == b"\x86\x0a"
        assert words(c.ask(10, 1, read_pdu(5, 1))) == [5]
        c.close()
        assert s.stop() == 0
    assert [r[2] << 8 | r[3] for r in device.requests] == [0, 1, 2, 3, 5]
    assert sum(r[1] == 6 for r in device.requests) == 0


class ResetsFirst(OneShot):
    """Its first connection: takes the requests sent on it, then resets it
    (SO_LINGER 0) without a reply, as a device that answers one request a
    connection does when its reply is lost with the reset. Then as
    :class:`OneShot`."""

    def _serve(self, conn: socket.socket) -> None:
        if self.connections:
            super()._serve(conn)
            return
        self.connections += 1
        buf, deadline = b"", time.monotonic() + 5
        while len(split_mbap(buf)[0]) < 3 and time.monotonic() < deadline:
            try:
                buf += conn.recv(1024)
            except TimeoutError:
                continue
        self.first = len(split_mbap(buf)[0])
        conn.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))


def test_reads_in_flight_on_a_connection_reset_before_any_reply_are_sent_again() -> None:
    with ResetsFirst() as device, Served("--tcp", f"127.0.0.1:{device.port}",
                                         "--timeout", "2") as s:
        c = RawClient(s.port)
        c.send(b"".join(struct.pack(">HHHBBHH", j, 0, 6, 1, 3, 20 + j, 1) for j in range(3)))
        assert [words(c.reply()[2]) for _ in range(3)] == [[20 + j] for j in range(3)]
        c.close()
        assert s.stop() == 0
    assert device.first == 3  # all three were in flight when it reset
    assert any("reset the connection before any reply was read, with 3 more request(s)"
               in line and "one transaction at a time from now" in line
               for line in s.stderr_lines), s.stderr_lines
    assert not any("0x0A" in line for line in s.stderr_lines), s.stderr_lines
