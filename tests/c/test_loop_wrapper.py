"""The C part of pymb log's TCP loop seen from Python (:mod:`pymb._native.loop`),
the way the loop drives it, against a peer on a real loopback TCP connection:
an armed connection's whole poll taken and the next one sent in one wait, a
take that is not the poll's clean end handed back with the master's events,
a connection not armed handed back untouched, a wait that holds the polls it
carried in its block ([MB-TCP] 3.1.3, [MB-APP] 6.3, 7)."""

from __future__ import annotations

import errno
import select
import socket
import time
from collections.abc import Iterator

import pytest

from pymb._native.loop import DONE, NO_CONN, READY, TAKEN, Loop
from pymb._native.master import EXCEPTION, Master, MasterRead, PollTable, ReadBuffer


def _regs(tid: int, fill: int, count: int) -> bytes:
    pdu = bytes((3, 2 * count)) + bytes(range(fill, fill + 2 * count))
    return tid.to_bytes(2, "big") + b"\x00\x00" + (len(pdu) + 1).to_bytes(2, "big") + b"\x07" + pdu


def _recv(s: socket.socket, n: int) -> bytes:
    got = b""
    while len(got) < n:
        got += s.recv(n - len(got))
    return got


class _Rig:
    """A connection to a peer, a poll of two reads framed and sent, and the loop over it."""

    def __init__(self, block: int = 0, hold: float = 0.0) -> None:
        lsock = socket.create_server(("127.0.0.1", 0))
        self.client = socket.create_connection(lsock.getsockname())
        self.peer, _ = lsock.accept()
        lsock.close()
        for s in (self.client, self.peer):
            s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.client.setblocking(False)
        self.ep = select.epoll()
        self.ep.register(self.client.fileno(), select.EPOLLIN)
        self.image = bytearray(12)
        self.t = PollTable([MasterRead(3, 0, 2, 8), MasterRead(3, 10, 4, 0)], 7, self.image)
        self.m = Master()
        self.rx = ReadBuffer()
        self.loop = Loop(self.ep.fileno(), 1, self.rx, 0.002, block=block, hold=hold)
        self.loop.bind(0, self.client.fileno())
        size = self.m.frames(self.t, 0, 2)
        self.client.send(self.m.view[:size])
        assert len(_recv(self.peer, size)) == 24
        self.client.setsockopt(socket.SOL_SOCKET, socket.SO_RCVLOWAT, self.t.ends[2])

    def close(self) -> None:
        self.ep.close()
        self.client.close()
        self.peer.close()


@pytest.fixture
def rig() -> Iterator[_Rig]:
    r = _Rig()
    yield r
    r.close()


def test_an_armed_poll_is_taken_and_the_next_one_sent(rig: _Rig) -> None:
    rig.loop.arm(0, rig.m, rig.t, 1.0, 0.0, 0.0, 1e12)
    rig.peer.send(_regs(2, 0x40, 4) + _regs(1, 0x80, 2))
    assert rig.loop.wait(2.0) == 0  # no record: the connection is in done
    assert rig.loop.done == [0]
    now = rig.loop.now
    assert bytes(rig.image) == bytes(range(0x40, 0x48)) + bytes(range(0x80, 0x84))
    nxt = _recv(rig.peer, 24)  # the same poll again, transactions 3 and 4
    assert nxt == bytes.fromhex("0003 0000 0006 07 03 0000 0002"
                                "0004 0000 0006 07 03 000a 0004".replace(" ", ""))
    with pytest.raises(BlockingIOError):  # the replies were dropped from the socket
        rig.client.recv(1)
    got = rig.loop.disarm(0)
    assert got.asked == 2
    assert got.sent_at == now
    assert got.deadline == now + 1.0
    assert now < got.look_at <= now + 0.25
    assert rig.m.in_flight == 2


def test_an_exception_is_handed_back_with_the_masters_event(rig: _Rig) -> None:
    rig.t.ends[2] = 13 + 9  # (as many bytes as one reply and an exception: taken)
    rig.client.setsockopt(socket.SOL_SOCKET, socket.SO_RCVLOWAT, 22)
    rig.loop.arm(0, rig.m, rig.t, 1.0, 0.0, 0.0, 1e12)
    rig.peer.send(_regs(1, 0x80, 2) + bytes.fromhex("0002 0000 0003 07 83 02"))
    assert rig.loop.wait(2.0) == 1
    r = rig.loop.recs[0]
    assert (r.kind, r.conn, r.nev, r.got, r.used, r.taken) == (TAKEN, 0, 1, 22, 22, 1)
    ev = rig.m.event(0)
    assert (ev.kind, ev.token, ev.code) == (EXCEPTION, 1, 2)
    assert rig.m.in_flight == 0
    assert rig.rx.data[13:22] == bytes.fromhex("0002 0000 0003 07 83 02".replace(" ", ""))
    assert rig.loop.disarm(0).asked == 0


def test_a_connection_not_armed_or_not_bound_is_handed_back_untouched(rig: _Rig) -> None:
    rig.peer.send(_regs(2, 0x40, 4) + _regs(1, 0x80, 2))
    assert rig.loop.wait(2.0) == 1
    r = rig.loop.recs[0]
    assert (r.kind, r.conn, r.fd) == (READY, 0, rig.client.fileno())
    assert r.events & select.EPOLLIN
    assert rig.m.replies == 0
    rig.loop.unbind(rig.client.fileno())
    assert rig.loop.wait(2.0) == 1
    assert (rig.loop.recs[0].kind, rig.loop.recs[0].conn) == (READY, NO_CONN)
    assert len(rig.client.recv(100)) == 17 + 13


def test_a_next_poll_that_cannot_go_out_is_a_record(rig: _Rig) -> None:
    rig.loop.arm(0, rig.m, rig.t, 1.0, 0.0, 0.0, 1e12)
    rig.client.shutdown(socket.SHUT_WR)  # (its sends fail: EPIPE)
    rig.peer.send(_regs(2, 0x40, 4) + _regs(1, 0x80, 2))
    assert rig.loop.wait(2.0) == 1
    assert rig.loop.done == []
    r = rig.loop.recs[0]
    assert (r.kind, r.conn, r.size, r.sent, r.err) == (DONE, 0, 24, 0, errno.EPIPE)
    assert bytes(rig.image) == bytes(range(0x40, 0x48)) + bytes(range(0x80, 0x84))
    assert rig.loop.disarm(0).asked == 2


def test_with_a_block_a_wait_holds_the_polls_it_carried_and_copies_their_images() -> None:
    r = _Rig(block=64, hold=0.05)
    try:
        r.loop.arm(0, r.m, r.t, 1.0, 0.0, 0.0, 1e12)
        r.peer.send(_regs(2, 0x40, 4) + _regs(1, 0x80, 2))
        t0 = time.monotonic()
        assert r.loop.wait(2.0) == 0
        assert time.monotonic() - r.loop.done_at[0] >= 0.045  # held on for more
        assert time.monotonic() - t0 < 1.0
        assert (r.loop.done, r.loop.done_off) == ([0], [0])
        assert r.loop.done_at[0] <= r.loop.now
        want = bytes(range(0x40, 0x48)) + bytes(range(0x80, 0x84))
        assert bytes(r.loop.block[:12]) == want == bytes(r.image)
        # the next poll went out; its replies are the next wait's, copied to the block's start
        assert len(_recv(r.peer, 24)) == 24
        r.peer.send(_regs(3, 0x10, 2) + _regs(4, 0x20, 4))
        assert r.loop.wait(2.0) == 0
        assert (r.loop.done, r.loop.done_off) == ([0], [0])
        assert bytes(r.loop.block[:12]) == bytes(range(0x20, 0x28)) + bytes(range(0x10, 0x14))
    finally:
        r.close()
