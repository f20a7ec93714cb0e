"""An async client's life under hostile use: a connect or a close whose
await is cancelled, a loop closed by hand with the client open, the task
count around close(). Real lines: TCP on 127.0.0.1 and the simulator."""

from __future__ import annotations

import asyncio
import contextlib
import gc
import socket
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Iterator

import pytest
from aiokit import fds, pymb_threads, until
from peerkit import mbap, registers
from wire_peers import RawTcp, tcp_request

import pymb
from pymb.aio import AsyncTcpClient


def answers(delay: float = 0.0) -> RawTcp:
    """A Modbus TCP device whose holding register N reads N, each reply
    ``delay`` seconds after its request."""
    def script(_: int, adu: bytes) -> list[tuple[float, bytes]]:
        tid, unit, pdu = tcp_request(adu)
        address, count = struct.unpack(">HH", pdu[1:5])
        return [(delay, mbap(tid, unit, pdu[:1] + registers(
            [address + i for i in range(count)])))]
    return RawTcp(script)


def guards() -> list[asyncio.Task[object]]:
    return [t for t in asyncio.all_tasks() if t.get_name().startswith("pymb-aio guard")]


def test_close_returns_with_its_guard_task_ended() -> None:
    async def main(port: int) -> None:
        tasks = len(asyncio.all_tasks())
        c = AsyncTcpClient("127.0.0.1", port, slave=1)
        await c.connect()
        assert len(guards()) == 1
        await c.close()
        assert len(asyncio.all_tasks()) == tasks  # at once, not a turn of the loop later

    with answers() as peer:
        asyncio.run(main(peer.port))


def test_a_failed_connect_leaves_no_guard_task() -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # bound, not listening: refused

        async def main() -> None:
            c = AsyncTcpClient("127.0.0.1", port, slave=1)
            with pytest.raises(pymb.ModbusConnectionError):
                await c.connect()
            assert guards() == []

        asyncio.run(main())


def test_a_cancelled_close_still_closes_the_line() -> None:
    # close() waits behind a slow job on the worker (a function of the
    # caller's, which no close can stop); its await gives up (wait_for): the
    # line is closed all the same once the job is done.
    async def main(port: int) -> None:
        c = AsyncTcpClient("127.0.0.1", port, slave=1, timeout=2.0)
        await c.connect()
        started = threading.Event()

        def slow_job() -> int:
            started.set()
            time.sleep(0.3)
            return 7

        slow = asyncio.ensure_future(c.run(slow_job))
        await until(started.is_set, "the job on the worker")
        with pytest.raises(TimeoutError):
            await asyncio.wait_for(c.close(), 0.05)
        assert await slow == 7  # the job ran to its end
        await until(lambda: not c.connected, "the line closed")
        await until(lambda: not pymb_threads(), "the worker ended")
        assert guards() == []
        with pytest.raises(pymb.ModbusConnectionError, match="not connected"):
            await c.read_holding_registers(7, 1)

    with answers() as peer:
        asyncio.run(main(peer.port))


@pytest.fixture
def backlogged() -> Iterator[tuple[int, socket.socket]]:
    """A listener whose accept queue is full: a new connection request is
    dropped until the test accepts the queued ones (the client's SYN is then
    answered when it is sent again, about a second later)."""
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(0)
    held = []
    for _ in range(3):
        s = socket.socket()
        s.setblocking(False)
        with contextlib.suppress(BlockingIOError):
            s.connect(srv.getsockname())
        held.append(s)
    time.sleep(0.1)
    try:
        yield srv.getsockname()[1], srv
    finally:
        for s in held:
            s.close()
        srv.close()


def test_a_connect_cancelled_midway_is_closed_at_the_loops_end(
        backlogged: tuple[int, socket.socket]) -> None:
    # The connect's await gives up while the worker waits for the SYN's
    # answer; the connection opens after that, and asyncio.run's end closes it.
    port, srv = backlogged
    gc.collect()
    before = fds()
    client: list[AsyncTcpClient] = []

    async def main() -> None:
        c = AsyncTcpClient("127.0.0.1", port, slave=1, timeout=5.0)
        client.append(c)
        with pytest.raises(TimeoutError):
            await asyncio.wait_for(c.connect(), 0.2)
        srv.settimeout(1.0)
        for _ in range(2):  # room in the accept queue: the next SYN is answered
            srv.accept()[0].close()

    asyncio.run(main())
    assert not client[0].connected
    assert pymb_threads() == []
    client.clear()
    gc.collect()
    assert fds() == before


LOOP_CLOSED_BY_HAND = """
import asyncio, gc, sys
import pymb.aio
from pymb.sim import Simulator

with Simulator(["coolpro:40"], transport="tcp") as sim:
    loop = asyncio.new_event_loop()
    kept = pymb.aio.AsyncTcpClient(sim.host, sim.tcp_port, slave=40)
    dropped = pymb.aio.AsyncTcpClient(sim.host, sim.tcp_port, slave=40)
    for c in (kept, dropped):
        loop.run_until_complete(c.connect())
        loop.run_until_complete(c.read_holding_registers(0, 1))
    loop.close()  # the guards never ran, nor were cancelled
    del loop, dropped
    gc.collect()
    print("done")
"""


def test_a_loop_closed_by_hand_with_clients_open_says_nothing_at_exit() -> None:
    # One client dropped, one still referenced when the interpreter exits.
    r = subprocess.run([sys.executable, "-c", LOOP_CLOSED_BY_HAND], capture_output=True,
                       text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert r.stdout == "done\n"
    assert "Task was destroyed" not in r.stderr, r.stderr
    assert "Traceback" not in r.stderr, r.stderr


def test_close_on_another_loop_after_the_first_was_closed_by_hand() -> None:
    with answers() as peer:
        c = AsyncTcpClient("127.0.0.1", peer.port, slave=1)
        first = asyncio.new_event_loop()
        first.run_until_complete(c.connect())
        first.close()
        asyncio.run(c.close())  # no "Event loop is closed" from the old guard
        assert not c.connected
        assert pymb_threads() == []


def test_close_lets_a_connect_in_progress_end_first(
        backlogged: tuple[int, socket.socket]) -> None:
    # Nobody answers the SYN: the connect ends at its 0.5 s timeout, and the
    # close() asked meanwhile closes after it (nothing is left open).
    port, _ = backlogged

    async def main() -> None:
        c = AsyncTcpClient("127.0.0.1", port, slave=1, timeout=0.5)
        t0 = time.monotonic()
        connecting = asyncio.ensure_future(c.connect())
        await asyncio.sleep(0.1)
        await c.close()
        assert time.monotonic() - t0 >= 0.45  # the connect had its time
        with pytest.raises(pymb.ModbusConnectionError, match="within the timeout"):
            await connecting
        assert not c.connected
        assert guards() == []
        assert pymb_threads() == []

    asyncio.run(main())
