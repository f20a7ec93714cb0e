"""The simulator's Modbus TCP server frames by the MBAP rules of the Modbus
Messaging on TCP/IP Implementation Guide (3.1.3): requests split by their
length field however the stream cuts them, a header that cannot be Modbus
TCP closes the connection, and the framing faults cut or extend the reply.
The master here is a raw socket, frames written from the guide."""

from __future__ import annotations

import socket
import struct
from collections.abc import Iterator

import pytest

from pymb.sim import Device, Simulator

READ = bytes.fromhex("0400000001")  # read input register 0, one register


def mbap(tid: int, unit: int, pdu: bytes) -> bytes:
    return struct.pack(">HHHB", tid, 0, len(pdu) + 1, unit) + pdu


def reply(sock: socket.socket) -> bytes:
    """One whole reply frame, by its own length field."""
    head = _exactly(sock, 6)
    return head + _exactly(sock, struct.unpack(">H", head[4:])[0])


def _exactly(sock: socket.socket, n: int) -> bytes:
    out = b""
    while len(out) < n:
        got = sock.recv(n - len(out))
        assert got, f"closed after {out.hex(' ')}"
        out += got
    return out


class Oversize(Device):
    """Answers every request with a PDU no MBAP frame holds (254 bytes)."""

    kind = "oversize"

    def handle(self, pdu: bytes) -> bytes | None:
        return pdu[:1] + bytes(253)


@pytest.fixture
def sim() -> Iterator[Simulator]:
    with Simulator(["coolpro:40", Oversize(7, baud=9600, seed=0, clock=None)],
                   transport="tcp") as s:
        yield s


def _connect(sim: Simulator) -> socket.socket:
    sock = socket.create_connection((sim.host, sim.tcp_port), timeout=5)
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return sock


def test_requests_are_split_by_their_length_however_the_stream_cuts_them(
        sim: Simulator) -> None:
    with _connect(sim) as sock:
        two = mbap(0x0102, 40, READ) + mbap(0x0304, 40, READ)
        sock.sendall(two[:3])  # the header cut short
        sock.sendall(two[3:15])  # the first request, and part of the second
        first = reply(sock)
        sock.sendall(two[15:])
        second = reply(sock)
    for frame, tid in ((first, 0x0102), (second, 0x0304)):
        assert frame[:7] == struct.pack(">HHHB", tid, 0, 5, 40)
        assert frame[7:9] == b"\x04\x02"


@pytest.mark.parametrize("bad", [
    struct.pack(">HHHB", 1, 1, 6, 40) + READ,  # protocol id 1
    struct.pack(">HHHB", 1, 0, 1, 40),  # a length with no PDU
    struct.pack(">HHHB", 1, 0, 255, 40) + bytes(254),  # a PDU over 253 bytes
])
def test_a_header_that_cannot_be_modbus_tcp_closes_the_connection(
        sim: Simulator, bad: bytes) -> None:
    with _connect(sim) as sock:
        sock.sendall(bad)
        assert sock.recv(16) == b""
    assert sim.stats.bad_frames == 1
    with _connect(sim) as sock:  # the next connection is served
        sock.sendall(mbap(9, 40, READ))
        assert reply(sock)[:9] == struct.pack(">HHHB", 9, 0, 5, 40) + b"\x04\x02"


def test_the_requests_before_a_bad_header_are_answered_then_the_connection_closes(
        sim: Simulator) -> None:
    with _connect(sim) as sock:  # one segment: a request, then protocol id 1
        sock.sendall(mbap(5, 40, READ) + struct.pack(">HHHB", 6, 1, 6, 40) + READ)
        assert reply(sock)[:9] == struct.pack(">HHHB", 5, 0, 5, 40) + b"\x04\x02"
        assert sock.recv(16) == b""
    assert sim.stats.bad_frames == 1


def test_framing_faults_on_tcp(sim: Simulator) -> None:
    with _connect(sim) as sock:
        sim.faults.inject("stray", extra=b"\xee\xff")
        sock.sendall(mbap(1, 40, READ))
        whole = reply(sock)
        assert _exactly(sock, 2) == b"\xee\xff"
        sim.faults.inject("wrong_address", to=41)
        sock.sendall(mbap(2, 40, READ))
        assert reply(sock)[:7] == struct.pack(">HHHB", 2, 0, 5, 41)
        sim.faults.inject("truncate", keep=5)
        sock.sendall(mbap(1, 40, READ))
        assert _exactly(sock, 5) == whole[:5]
    assert sim.faults.counts["stray"] == sim.faults.counts["truncate"] == 1


def test_a_reply_no_frame_holds_is_not_sent_and_the_server_goes_on(
        sim: Simulator, caplog: pytest.LogCaptureFixture) -> None:
    with _connect(sim) as sock:
        sock.settimeout(0.5)
        sock.sendall(mbap(1, 7, READ))
        with pytest.raises(TimeoutError):
            sock.recv(16)
        sock.settimeout(5)
        sock.sendall(mbap(2, 40, READ))
        assert reply(sock)[:7] == struct.pack(">HHHB", 2, 0, 5, 40)
    assert "oversize at address 7: a reply PDU holds 1..253 bytes, got 254: not sent" \
        in caplog.text
