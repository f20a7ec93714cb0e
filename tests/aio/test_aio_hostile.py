"""pymb.aio driven as hostile programs drive it: a thousand requests
cancelled at random moments, fifty tasks on one client with one of them
asking a silent device, a reply later than the client's timeout, a server
that goes away and comes back. Every answer is the asker's own (each
register reads its own address), and nothing is left behind: descriptors,
threads and tasks are counted before and after. Real peers: a
pseudo-terminal (RTU and ASCII), TCP and UDP on 127.0.0.1."""

from __future__ import annotations

import asyncio
import gc
import random
import socket
import struct
import threading
import time
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager

import pytest
from aiokit import fds
from peerkit import Reply, ThreadedPeer, mbap, registers, rtu, rtu_crc_ok
from wire_peers import RawPty, RawTcp, tcp_request

import pymb
import pymb.aio

SILENT = 9  #: the unit/slave that never answers


def tcp_script(delay: Callable[[int], float]) -> Callable[[int, bytes], Reply]:
    """Unit 1's register N reads N, ``delay(index)`` seconds after the request."""
    def script(index: int, adu: bytes) -> Reply:
        tid, unit, pdu = tcp_request(adu)
        if unit == SILENT:
            return []
        address, count = struct.unpack(">HH", pdu[1:5])
        return [(delay(index), mbap(tid, unit, pdu[:1] + registers(
            [(address + i) & 0xFFFF for i in range(count)])))]
    return script


def rtu_script(_: int, frame: bytes) -> Reply:
    if not rtu_crc_ok(frame) or frame[0] == SILENT:
        return []
    address, count = struct.unpack(">HH", frame[2:6])
    return [(0.0, rtu(frame[:2] + registers([(address + i) & 0xFFFF for i in range(count)])))]


def ascii_script(_: int, frame: bytes) -> Reply:
    """rtu_script's device in Modbus ASCII ([MB-SL] 2.5.2: hex digits, LRC)."""
    body = bytes.fromhex(frame.strip()[1:].decode())
    if body[0] == SILENT:
        return []
    address, count = struct.unpack(">HH", body[2:6])
    reply = body[:2] + registers([(address + i) & 0xFFFF for i in range(count)])
    return [(0.0, b":" + (reply + bytes((-sum(reply) & 0xFF,))).hex().upper().encode()
             + b"\r\n")]


class UdpPeer(ThreadedPeer):
    """Unit 1's register N reads N over Modbus UDP, after up to 1 ms."""

    def __init__(self) -> None:
        super().__init__()
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.05)
        self.port = self.sock.getsockname()[1]
        self.rng = random.Random(5)

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                adu, peer = self.sock.recvfrom(600)
            except OSError:
                continue
            out = tcp_script(lambda _: 0.0)(0, adu)
            time.sleep(self.rng.random() * 0.001)
            for _, data in out:
                self.sock.sendto(data, peer)

    def _close(self) -> None:
        self.sock.close()


@asynccontextmanager
async def client_of(kind: str) -> AsyncIterator[pymb.aio.AsyncClient]:
    rng = random.Random(11)
    c: pymb.aio.AsyncClient
    if kind == "rtu":
        with RawPty(rtu_script) as pty:
            c = pymb.aio.AsyncRtuClient(pty.port, 115200, slave=1, timeout=0.5)
            async with c:
                yield c
    elif kind == "ascii":
        with RawPty(ascii_script) as pty:
            c = pymb.aio.AsyncAsciiClient(pty.port, 115200, slave=1, timeout=0.5)
            async with c:
                yield c
    elif kind == "udp":
        with UdpPeer() as udp:
            c = pymb.aio.AsyncUdpClient("127.0.0.1", udp.port, slave=1, timeout=0.5)
            async with c:
                yield c
    else:
        with RawTcp(tcp_script(lambda _: rng.random() * 0.002)) as tcp:
            c = pymb.aio.AsyncTcpClient("127.0.0.1", tcp.port, slave=1, timeout=0.5)
            async with c:
                yield c


def held() -> tuple[set[str], set[str]]:
    """This process's descriptors and threads (by name and id)."""
    gc.collect()
    return fds(), {f"{t.name} {t.ident}" for t in threading.enumerate()}


@pytest.mark.parametrize(("kind", "n"),
                         [("tcp", 1000), ("udp", 1000), ("rtu", 300), ("ascii", 300)])
def test_cancelled_requests_leave_nothing_and_never_shift_a_reply(kind: str, n: int) -> None:
    rng = random.Random(17)

    async def main() -> None:
        async with client_of(kind) as c:
            await c.read_holding_registers(0, 1)  # the worker and the line are up
            before, tasks = held(), len(asyncio.all_tasks())
            cancelled = 0
            for _ in range(n):
                address = rng.randrange(0, 65000)
                read = asyncio.ensure_future(c.read_holding_registers(address, 3))
                await asyncio.sleep(rng.random() * 0.002)
                read.cancel()
                try:
                    got = await read
                except asyncio.CancelledError:
                    cancelled += 1
                    continue
                assert list(got) == [address, address + 1, address + 2]
            assert cancelled > 0, "no request was cancelled before its reply came"
            for address in range(0, 5000, 100):  # the next answers are their own
                assert list(await c.read_holding_registers(address, 2)) == [address, address + 1]
            assert held() == before
            assert len(asyncio.all_tasks()) == tasks

    asyncio.run(main())


@pytest.mark.parametrize("kind", ["tcp", "udp", "rtu", "ascii"])
def test_fifty_tasks_on_one_client_each_get_their_own_values(kind: str) -> None:
    async def main() -> None:
        async with client_of(kind) as c:
            async def reader(k: int) -> list[tuple[int, list[int]]]:
                wrong = []
                for i in range(10):
                    address = 1000 * k + 7 * i
                    got = list(await c.read_holding_registers(address, 4))
                    if got != [address + j for j in range(4)]:
                        wrong.append((address, got))
                return wrong

            async def silent() -> BaseException:
                with pytest.raises(pymb.ModbusTimeout) as ei:
                    await c.read_holding_registers(1, 1, slave=SILENT)
                return ei.value

            results = await asyncio.wait_for(
                asyncio.gather(*(reader(k) for k in range(50)), silent()), 60)
            assert all(r == [] for r in results[:50]), [r for r in results[:50] if r]

    asyncio.run(main())


def test_a_reply_after_the_timeout_is_dropped_by_its_transaction_id() -> None:
    async def main(port: int) -> None:
        async with pymb.aio.AsyncTcpClient("127.0.0.1", port, slave=1, timeout=0.2) as c:
            with pytest.raises(pymb.ModbusTimeout):
                await c.read_holding_registers(10, 1)  # its reply comes at 0.35 s
            assert list(await c.read_holding_registers(20, 1)) == [20]
            with pytest.raises(TimeoutError):  # an asyncio timeout, the same
                await asyncio.wait_for(c.read_holding_registers(30, 1), 0.05)
            assert list(await c.read_holding_registers(40, 1)) == [40]

    slow_first = {0, 2}
    with RawTcp(tcp_script(lambda i: 0.35 if i in slow_first else 0.0)) as peer:
        asyncio.run(main(peer.port))


def test_a_server_that_goes_away_and_comes_back() -> None:
    async def main() -> None:
        peer = RawTcp(tcp_script(lambda _: 0.0)).__enter__()
        port = peer.port
        async with pymb.aio.AsyncTcpClient("127.0.0.1", port, slave=1, timeout=1.0) as c:
            assert list(await c.read_holding_registers(5, 1)) == [5]
            peer.stop()
            with pytest.raises(pymb.ModbusConnectionError):
                await c.read_holding_registers(6, 1)
            with RawTcp(tcp_script(lambda _: 0.0), port=port):  # the same port again
                assert list(await c.read_holding_registers(7, 1)) == [7]
                assert c.connections == 2

    asyncio.run(main())
