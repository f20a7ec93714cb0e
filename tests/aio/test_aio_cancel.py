"""Cancellation: a cancelled await never leaves a half-sent frame or a reply
a later request could take. Not yet started: never sent. On the wire: the
request completes on the worker and its outcome is dropped; the next
request goes out only after it. asyncio timeouts (wait_for) are
cancellations too; the client's own timeout still bounds the line."""

from __future__ import annotations

import asyncio
import struct
from collections.abc import Callable

import pytest
from aiokit import until
from peerkit import Reply, registers, rtu, rtu_crc_ok
from wire_peers import RawPty, RawTcp

import pymb
from pymb.aio import AsyncRtuClient, AsyncRtuOverTcpClient
from pymb.sim import Simulator

pytest_plugins = ["pymb.testing"]


def value_of(address: int) -> int:
    return 1000 + address


def split_reply(first_delay: float, rest_delay: float) -> Callable[[int, bytes], Reply]:
    """Holding register N reads 1000 + N; each reply is sent in two halves,
    ``rest_delay`` apart (a frame in the middle of arriving)."""
    def script(_: int, frame: bytes) -> Reply:
        if not rtu_crc_ok(frame):
            return []
        address, count = struct.unpack(">HH", frame[2:6])
        reply = rtu(bytes((frame[0], 3)) + registers(
            [value_of(address + i) for i in range(count)]))
        return [(first_delay, reply[:4]), (rest_delay, reply[4:])]
    return script


def addresses(requests: list[bytes]) -> list[int]:
    return [struct.unpack(">H", f[2:4])[0] for f in requests]


def test_cancelled_mid_frame_the_reply_is_not_taken_by_the_next_request() -> None:
    async def main(peer: RawPty) -> None:
        async with AsyncRtuClient(peer.port, 115200, slave=1, timeout=2.0) as c:
            first = asyncio.ensure_future(c.read_holding_registers(10, 3))
            # the reply's first half is on the line, the rest 0.3 s away
            await until(lambda: peer.written >= 1, "half of the first reply")
            first.cancel()
            with pytest.raises(asyncio.CancelledError):
                await first  # at once: the caller does not wait for the line
            assert peer.written == 1  # ... the rest of the frame is still to come
            second = await c.read_holding_registers(20, 3)
            assert list(second) == [1020, 1021, 1022]
            # both halves of both replies (the peer counts a piece after writing it,
            # so the count may follow the bytes the read has already taken)
            await until(lambda: peer.written >= 4, "both halves of both replies")
            assert peer.written == 4

    with RawPty(split_reply(0.0, 0.3)) as peer:
        asyncio.run(main(peer))
        assert addresses(peer.requests) == [10, 20]
        assert all(rtu_crc_ok(f) for f in peer.requests)


def test_cancelled_before_its_turn_a_request_is_never_sent() -> None:
    async def main(peer: RawPty) -> None:
        async with AsyncRtuClient(peer.port, 115200, slave=1, timeout=2.0) as c:
            running = asyncio.ensure_future(c.read_holding_registers(1, 1))
            queued = [asyncio.ensure_future(c.read_holding_registers(a, 1)) for a in (2, 3, 4)]
            await until(lambda: len(peer.requests) == 1, "the first request on the wire")
            queued[1].cancel()
            got = await asyncio.gather(running, *queued, return_exceptions=True)
            assert [list(g) if not isinstance(g, BaseException) else "cancelled"
                    for g in got] == [[1001], [1002], "cancelled", [1004]]

    with RawPty(split_reply(0.1, 0.0)) as peer:
        asyncio.run(main(peer))
        assert addresses(peer.requests) == [1, 2, 4]


def test_wait_for_gives_up_waiting_and_the_line_stays_clean() -> None:
    async def main(peer: RawPty) -> None:
        async with AsyncRtuClient(peer.port, 115200, slave=1, timeout=2.0) as c:
            with pytest.raises(TimeoutError):
                await asyncio.wait_for(c.read_holding_registers(5, 2), 0.05)
            assert list(await c.read_holding_registers(6, 2)) == [1006, 1007]

    with RawPty(split_reply(0.3, 0.0)) as peer:
        asyncio.run(main(peer))
        assert addresses(peer.requests) == [5, 6]


def test_a_late_reply_after_the_timeout_is_never_the_next_answer() -> None:
    # The first reply comes after the client's timeout: the next request
    # waits for the quiet window, so the stale reply is dropped, not taken.
    def script(index: int, frame: bytes) -> Reply:
        address = struct.unpack(">H", frame[2:4])[0]
        reply = rtu(bytes((1, 3)) + registers([value_of(address)]))
        return [(0.35 if index == 0 else 0.0, reply)]

    async def main(peer: RawPty) -> None:
        async with AsyncRtuClient(peer.port, 115200, slave=1, timeout=0.2) as c:
            with pytest.raises(pymb.ModbusTimeout):
                await c.read_holding_registers(1, 1)
            assert list(await c.read_holding_registers(2, 1)) == [1002]

    with RawPty(script) as peer:
        asyncio.run(main(peer))


def test_cancelling_a_hub_sweep_mid_way_keeps_the_next_sweep_whole(
        pymb_simulator: Callable[..., Simulator]) -> None:
    from pymb.aio import AsyncSensorHub

    sim = pymb_simulator("hub:1,dynamic=0", baud=115200)  # frames take their wire time

    async def main() -> None:
        async with AsyncRtuClient(sim.port, 115200, timeout=1.0) as c:
            hub = AsyncSensorHub(c, 1)
            whole = await hub.read_all()
            before = sim.stats.requests
            sweep = asyncio.ensure_future(hub.read_all())
            await until(lambda: sim.stats.requests > before, "the sweep's first request")
            sweep.cancel()
            again = await hub.read_all()
            assert sim.stats.requests == before + 12  # two whole sweeps of 6 requests
            # the same layout (which sensors are off), values of this moment
            assert [r == 0xFFFF for r in again.registers] == \
                [r == 0xFFFF for r in whole.registers]

    asyncio.run(main())


def test_cancelled_over_rtu_over_tcp_too() -> None:
    def script(_: int, frame: bytes) -> Reply:
        address = struct.unpack(">H", frame[2:4])[0]
        reply = rtu(bytes((1, 3)) + registers([value_of(address)]))
        return [(0.0, reply[:3]), (0.2, reply[3:])]

    async def main(peer: RawTcp) -> None:
        async with AsyncRtuOverTcpClient("127.0.0.1", peer.port, slave=1, timeout=1.0) as c:
            first = asyncio.ensure_future(c.read_holding_registers(1, 1))
            await until(lambda: len(peer.requests) == 1, "the first request")
            first.cancel()
            assert list(await c.read_holding_registers(2, 1)) == [1002]

    with RawTcp(script, rtu_frames=True) as peer:
        asyncio.run(main(peer))
        assert addresses(peer.requests) == [1, 2]


def test_many_tasks_cancelled_at_random_never_get_a_wrong_answer() -> None:
    # 20 tasks, 10 reads each, a third of them cancelled at seeded random
    # moments (queued, on the wire, in the middle of the reply): every read
    # that completes has its own answer, every frame on the line is whole.
    import random

    rng = random.Random(23)

    async def main(peer: RawPty) -> tuple[int, int]:
        done = cancelled = 0
        async with AsyncRtuClient(peer.port, 115200, slave=1, timeout=2.0) as c:
            async def worker(k: int) -> None:
                nonlocal done, cancelled
                for i in range(10):
                    address = 100 * k + i
                    read = asyncio.ensure_future(c.read_holding_registers(address, 2))
                    if rng.random() < 0.33:
                        await asyncio.sleep(rng.random() * 0.004)
                        read.cancel()
                    try:
                        got = await read
                    except asyncio.CancelledError:
                        cancelled += 1
                        continue
                    assert list(got) == [value_of(address), value_of(address + 1)]
                    done += 1

            await asyncio.gather(*(worker(k) for k in range(20)))
        return done, cancelled

    with RawPty(split_reply(0.0, 0.001)) as peer:
        done, cancelled = asyncio.run(main(peer))
        assert done + cancelled == 200
        assert done >= 100
        assert cancelled >= 30
        assert all(rtu_crc_ok(f) and len(f) == 8 for f in peer.requests)
        sent = addresses(peer.requests)
        assert len(sent) == len(set(sent)) >= done  # none sent twice, none lost
