"""TcpClient.attach: requests over a connected socket of the caller's (the
TCP loop lends its poll connection so), against a scripted Modbus TCP peer
that serves one connection at a time: the client's close leaves the caller's
connection open and usable, and a lost borrowed connection is not opened
again by the client."""

from __future__ import annotations

import socket
import struct

import pytest
from peerkit import Reply
from wire_peers import RawTcp, answer_read
from write_peers import FreezingTcpPeer

import pymb


def test_attach_uses_the_callers_connection_and_leaves_it_open() -> None:
    with FreezingTcpPeer() as peer:
        peer.memory.holding[5] = 1234
        sock = socket.create_connection(("127.0.0.1", peer.port), timeout=5)
        try:
            client = pymb.TcpClient("127.0.0.1", peer.port, timeout=2.0)
            client.attach(sock.fileno())
            assert list(client.read_holding_registers(5, 1, slave=1)) == [1234]
            client.write_register(5, 4321, slave=1)
            client.close()
            # the caller's connection still works (the peer serves one at a time:
            # a second connection would not be answered)
            sock.sendall(struct.pack(">HHHBBHH", 7, 0, 6, 1, 3, 5, 1))
            reply = sock.recv(64)
            assert reply == struct.pack(">HHHBBBH", 7, 0, 5, 1, 3, 2, 4321)
            # a lost borrowed connection stays lost: never a connection of the client's
            client.attach(sock.fileno())
            sock.shutdown(socket.SHUT_RDWR)
            with pytest.raises(pymb.ModbusConnectionError):
                client.read_holding_registers(5, 1, slave=1)
            with pytest.raises(pymb.ModbusConnectionError, match="borrowed"):
                client.read_holding_registers(5, 1, slave=1)
            client.close()
            assert peer.functions() == [3, 6, 3]
        finally:
            sock.close()


def test_attach_takes_the_callers_next_transaction_id() -> None:
    # docs/library.md: attach(fd, tid=N) gives the first request id N, and
    # next_tid says the next one (the ids go on past 0xFFFF to 0).
    seen: list[int] = []

    def script(i: int, adu: bytes) -> Reply:
        seen.append(int.from_bytes(adu[:2], "big"))
        return [(0, answer_read(adu, [i]))]

    with RawTcp(script) as peer, socket.create_connection(("127.0.0.1", peer.port),
                                                          timeout=5) as sock:
        client = pymb.TcpClient("127.0.0.1", peer.port, timeout=2.0)
        assert client.next_tid is None
        client.attach(sock.fileno(), tid=0xFFFE)
        assert client.next_tid == 0xFFFE
        assert [client.read_holding_registers(0, 1, slave=1)[0] for _ in range(3)] == [0, 1, 2]
        assert seen == [0xFFFE, 0xFFFF, 0]
        assert client.next_tid == 1
        client.close()
        assert client.next_tid is None
