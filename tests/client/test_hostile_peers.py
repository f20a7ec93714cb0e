"""Modbus masters against peers that misbehave, scripted from the
specifications ([MB-TCP] 3.1.3's MBAP header, [MB-SL] 2.5.1's RTU frame):
replies cut short, byte counts that lie, datagrams that are no answer.
Each case checks what a user sees: the error's class and words, within the
timeout, and never a wrong value afterwards."""

from __future__ import annotations

import socket
import threading
import time

import pytest
from peerkit import Reply, mbap, registers, rtu
from wire_peers import RawPty, RawTcp, UdpPeer, answer_read, udp_read_reply

import pymb


def test_tcp_a_reply_cut_short_says_what_came() -> None:
    # The reply stops in its MBAP header, then in its PDU: each is a timeout
    # that names the bytes the device did send (not "the device is silent").
    def script(i: int, adu: bytes) -> Reply:
        whole = answer_read(adu, [7])
        return [(0, whole[:5] if i == 0 else whole[:8] if i == 1 else whole)]

    with RawTcp(script) as peer, pymb.TcpClient("127.0.0.1", peer.port, slave=1,
                                                timeout=0.3) as c:
        with pytest.raises(pymb.ModbusTimeout, match=r"incomplete after 5 bytes"):
            c.read_holding_registers(0, 1)
        with pytest.raises(pymb.ModbusTimeout, match=r"incomplete after 8 bytes.* 01 03\)"):
            c.read_holding_registers(0, 1)
        assert list(c.read_holding_registers(0, 1)) == [7]


def test_tcp_a_reply_byte_by_byte_and_two_in_one_segment() -> None:
    # [MB-TCP] 3.1.3: the stream carries frames, not segments: a reply in
    # 11 pieces is one reply; an old transaction's reply and the answer in
    # one segment are two, and only the answer is taken.
    def script(i: int, adu: bytes) -> Reply:
        whole = answer_read(adu, [i])
        if i == 0:
            return [(0.002, whole[k:k + 1]) for k in range(len(whole))]
        old = mbap(int.from_bytes(adu[:2], "big") - 1, 1, bytes((3,)) + registers([99]))
        return [(0, old + whole)]

    with RawTcp(script) as peer, pymb.TcpClient("127.0.0.1", peer.port, slave=1,
                                                timeout=2) as c:
        assert [c.read_holding_registers(0, 1)[0] for _ in range(3)] == [0, 1, 2]


@pytest.mark.parametrize("length", [0, 1, 255, 0xFFFF])
def test_tcp_an_impossible_mbap_length_is_a_protocol_error(length: int) -> None:
    # [MB-TCP] 3.1.3: the length counts the unit id and the PDU, 2..254.
    # Anything else cannot be framed: refused at once, and after the quiet
    # window the stream owes, the next read gets its own answer.
    def script(i: int, adu: bytes) -> Reply:
        if i == 0:
            return [(0, mbap(int.from_bytes(adu[:2], "big"), 1, b"\x03\x02\x00\x09",
                             length=length))]
        return [(0, answer_read(adu, [i]))]

    with RawTcp(script) as peer, pymb.TcpClient("127.0.0.1", peer.port, slave=1,
                                                timeout=2.0) as c:
        t0 = time.monotonic()
        with pytest.raises(pymb.ProtocolError, match=r"MBAP header"):
            c.read_holding_registers(0, 1)
        assert time.monotonic() - t0 < 1.0  # at once, not at the timeout
        assert list(c.read_holding_registers(0, 1)) == [1]


def test_tcp_a_peer_that_closes_mid_reply() -> None:
    # The connection ends 5 bytes into the reply: a connection error at once
    # (not a timeout), and the next read connects again and gets its answer.
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]

    def serve() -> None:
        for k in range(2):
            conn, _ = server.accept()
            with conn:
                adu = conn.recv(256)
                conn.sendall(answer_read(adu, [k])[:5 if k == 0 else None])
                if k == 1:
                    conn.recv(256)  # until the client closes

    t = threading.Thread(target=serve, daemon=True)
    t.start()
    try:
        with pymb.TcpClient("127.0.0.1", port, slave=1, timeout=2) as c:
            t0 = time.monotonic()
            with pytest.raises(pymb.ModbusConnectionError, match=r"closed by the peer"):
                c.read_holding_registers(0, 1)
            assert time.monotonic() - t0 < 1
            assert list(c.read_holding_registers(0, 1)) == [1]
    finally:
        t.join(5)
        server.close()


def test_rtu_a_byte_count_shorter_than_its_frame_says_so() -> None:
    # The byte count (1) ends the frame before its data and CRC do: the CRC
    # fails there, but is right over all the device sent, so the error names
    # the length, not the CRC.
    def script(i: int, frame: bytes) -> Reply:
        return [(0, rtu(bytes((frame[0], 3, 1, 0, 9))))]

    with RawPty(script) as pty, pymb.RtuClient(pty.port, 115200, slave=1, timeout=0.3) as c, \
            pytest.raises(pymb.ProtocolError, match=r"byte count does not match"):
        c.read_holding_registers(0, 1)


def test_rtu_a_byte_count_longer_than_its_frame_is_a_protocol_error() -> None:
    # A whole frame, its CRC right, whose byte count (4) says more than it
    # carries (2 bytes): refused for its length once the timeout ends the
    # wait for the rest, not reported as a reply that stopped.
    def script(i: int, frame: bytes) -> Reply:
        if i == 0:
            return [(0, rtu(bytes((frame[0], 3, 4, 0, 9))))]
        return [(0, rtu(bytes((frame[0], 3)) + registers([i])))]

    with RawPty(script) as pty, pymb.RtuClient(pty.port, 115200, slave=1, timeout=0.3) as c:
        t0 = time.monotonic()
        with pytest.raises(pymb.ProtocolError, match=r"byte count does not match"):
            c.read_holding_registers(0, 1)
        assert time.monotonic() - t0 < 0.3 + 0.2
        assert list(c.read_holding_registers(0, 1)) == [1]


def test_udp_datagrams_of_the_wrong_size_or_from_elsewhere_are_dropped() -> None:
    # [MB-TCP] 3.1.3 over UDP: a datagram is one whole frame. Before each
    # answer come one shorter than an MBAP header, one longer than its MBAP
    # length says, one shorter, one longer than any ADU (260 bytes), and a
    # right-looking reply from another port of the host: all dropped.
    stranger = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    stranger.bind(("127.0.0.1", 0))
    clients: list[tuple[str, int]] = []

    def script(i: int, req: bytes) -> Reply:
        right = udp_read_reply(req, [i])
        tid = int.from_bytes(req[:2], "big")
        body = bytes((3,)) + registers([666])
        stranger.sendto(right[:6] + bytes((5, 3, 2, 2, 0x9A)), clients[-1])
        return [(0, right[:6]), (0, right + b"\x00"), (0, right[:-1]),
                (0, mbap(tid, 5, body + bytes(260), length=len(body) + 1)),
                (0, mbap(tid, 5, body, length=len(body) + 3)),
                (0.01, right)]

    with UdpPeer(script) as peer, pymb.UdpClient("127.0.0.1", peer.port, slave=5,
                                                 timeout=1, retries=0) as c:
        with socket.socket(fileno=c.fileno()) as s:
            clients.append(s.getsockname())
            s.detach()
        try:
            assert [c.read_holding_registers(0, 1)[0] for _ in range(3)] == [0, 1, 2]
        finally:
            stranger.close()


def test_tcp_replies_to_another_transaction_are_shown_by_the_timeout() -> None:
    # A device that answers with transaction id 0 whatever the request's (it
    # does not echo the id, [MB-TCP] 3.1.3): no answer, but not "silent".
    def script(i: int, adu: bytes) -> Reply:
        return [(0, mbap(0, 1, bytes((3,)) + registers([9])))]

    with RawTcp(script) as peer, pymb.TcpClient("127.0.0.1", peer.port, slave=1,
                                                timeout=0.3) as c, \
            pytest.raises(pymb.ModbusTimeout, match=r"within the 0.3 s timeout; what came was "
                          r"not the answer: reply to another transaction id \(received 00 00"):
        c.read_holding_registers(0, 1)


def test_udp_a_timeout_says_its_sends_and_what_was_dropped() -> None:
    # Every send is answered from another unit: dropped, and the read fails
    # after (retries + 1) * timeout with a timeout that says both.
    def script(i: int, req: bytes) -> Reply:
        return [(0, udp_read_reply(req, [9], unit=6))]

    with UdpPeer(script) as peer, pymb.UdpClient("127.0.0.1", peer.port, slave=5,
                                                 timeout=0.2, retries=2) as c:
        t0 = time.monotonic()
        with pytest.raises(pymb.ModbusTimeout,
                           match=r"within the 0.2 s timeout to any of 3 sends; what came was not "
                           r"the answer: reply from another address \(received .* 06 03 02"):
            c.read_holding_registers(0, 1)
        assert 0.6 <= time.monotonic() - t0 < 0.6 + 0.3
        assert len(peer.requests) == 3
