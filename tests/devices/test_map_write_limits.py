"""A write's requests within the limits of Modbus and of the map (pymb.write/1
section 1.3, pymb.map/1 section 4), against the scripted TCP peer of
tests/write_peers.py: an FC 16 carries at most 123 registers and never
splits a point, so two long points go in two requests; a point longer than
one request is refused before any byte; the reads before and after a write
keep the map's ``max_registers`` and never split a point."""

from __future__ import annotations

import struct
from collections.abc import Iterator

import pytest
from write_peers import FreezingTcpPeer

import pymb
from pymb import maps
from pymb.devices.mapdevice import MapDevice

HEAD = 'schema = "pymb.map/1"\n[device]\nid = "lim"\ntable = "holding"\n'


def text_point(name: str, address: int, count: int) -> str:
    return (f'[[point]]\nname = "{name}"\naddress = {address}\ntype = "string"\n'
            f'count = {count}\naccess = "rw"\n')


@pytest.fixture
def peer() -> Iterator[FreezingTcpPeer]:
    with FreezingTcpPeer() as p:
        yield p


def spans(peer: FreezingTcpPeer, function: int) -> list[tuple[int, int]]:
    """(address, count) of every request of ``function`` the peer received."""
    return [struct.unpack(">HH", pdu[1:5]) for _, pdu in peer.requests if pdu[0] == function]


def test_two_long_points_go_in_two_fc16_requests(peer: FreezingTcpPeer) -> None:
    m = maps.loads(HEAD + text_point("a", 0, 100) + text_point("b", 100, 100), source="lim.toml")
    with pymb.TcpClient("127.0.0.1", peer.port, timeout=5.0) as c:
        dev = MapDevice(c, m, 1)
        assert [(r.function, r.address, len(r.values)) for r in
                dev.plan_write({"a": "x" * 200, "b": "y" * 200})] == [(16, 0, 100), (16, 100, 100)]
        assert dev.write_many({"a": "x" * 200, "b": "y" * 200}) == {"a": "x" * 200,
                                                                  "b": "y" * 200}
    assert spans(peer, 16) == [(0, 100), (100, 100)]
    assert all(count <= 125 for _, count in spans(peer, 3))


def test_a_point_longer_than_one_write_request_is_refused_before_any_byte(
        peer: FreezingTcpPeer) -> None:
    m = maps.loads(HEAD + text_point("long", 0, 124), source="lim.toml")
    with pymb.TcpClient("127.0.0.1", peer.port, timeout=5.0) as c:
        dev = MapDevice(c, m, 1)
        for call in (lambda: dev.plan_write({"long": "x"}), lambda: dev.write("long", "x")):
            with pytest.raises(pymb.InvalidArgument) as info:
                call()
            assert str(info.value) == ("lim: point 'long': its 124 registers do not fit one "
                                       "write request (FC 16 writes at most 123)")
    assert peer.requests == []


def test_reads_around_a_write_keep_max_registers_and_whole_points(
        peer: FreezingTcpPeer) -> None:
    body = '[device.limits]\nmax_registers = 4\n' + "".join(
        f'[[point]]\nname = "p{k}"\naddress = {2 * k}\ntype = "u32"\naccess = "rw"\n'
        f'max_writes_per_hour = 10\n' for k in range(3))  # a budget: each is read first
    m = maps.loads(HEAD + body, source="lim.toml")

    def refuse_long_reads(slave: int, pdu: bytes, normal: bytes | None) -> list[tuple[float,
                                                                                    bytes]] | None:
        if pdu[0] == 3 and struct.unpack(">H", pdu[3:5])[0] > 4:
            return [(0.0, peer.frame(slave, b"\x83\x03"))]
        return None

    peer.hook = refuse_long_reads
    with pymb.TcpClient("127.0.0.1", peer.port, timeout=5.0) as c:
        dev = MapDevice(c, m, 1)
        assert dev.write_many({"p0": 1, "p1": 2, "p2": 3}) == {"p0": 1, "p1": 2, "p2": 3}
    reads = spans(peer, 3)
    assert reads == [(0, 4), (4, 2), (0, 4), (4, 2)]  # before and after: whole u32s, <= 4
    assert peer.memory.holding[:6] == [0, 1, 0, 2, 0, 3]
