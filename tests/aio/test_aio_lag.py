"""The event loop is never blocked: eight async clients poll eight hubs
(each simulator in its own process, emulating 115200 baud) flat out while a
10 ms ticker measures the loop's lag. The same probe sees pymb's blocking
calls made from coroutines stall the loop for whole sweeps, so it can fail.

The bound (p99 under 5 ms) is wall-clock sensitive: it runs under
the ``timing`` marker; the default run checks a bound that only a blocked
loop misses (a sweep at 115200 takes over 100 ms on the wire)."""

from __future__ import annotations

import asyncio
from collections.abc import Iterator

import pytest
from aiokit import Ticker

from pymb import RtuClient
from pymb.aio import AsyncRtuClient, AsyncSensorHub
from pymb.bench.procs import Children
from pymb.devices import SensorHub

HUBS = 8
BAUD = 115200


@pytest.fixture(scope="module")
def hub_ports() -> Iterator[list[str]]:
    """Eight simulator processes, one hub each, emulating 115200 baud."""
    with Children() as children:
        sims = children.sims([["hub:1,dynamic=0", "--baud", str(BAUD)] for _ in range(HUBS)])
        yield [s.port for s in sims]


async def poll_async(ports: list[str], seconds: float) -> tuple[Ticker, list[int]]:
    clients = [AsyncRtuClient(p, BAUD, timeout=2.0) for p in ports]
    counts = [0] * len(ports)
    loop = asyncio.get_running_loop()
    for c in clients:
        await c.connect()
    try:
        hubs = [AsyncSensorHub(c, 1) for c in clients]
        await asyncio.gather(*(h.read_all() for h in hubs))  # warm: plans made

        async def poll(i: int) -> None:
            end = loop.time() + seconds
            async for _ in hubs[i].poll(0):
                counts[i] += 1
                if loop.time() > end:
                    return

        ticker = Ticker().start()
        await asyncio.gather(*(poll(i) for i in range(len(hubs))))
        await ticker.stop()
    finally:
        await asyncio.gather(*(c.close() for c in clients))
    return ticker, counts


async def poll_blocking_in_the_loop(ports: list[str], seconds: float) -> Ticker:
    clients = [RtuClient(p, BAUD, timeout=2.0) for p in ports]
    loop = asyncio.get_running_loop()
    try:
        hubs = [SensorHub(c, 1) for c in clients]
        for c in clients:
            c.connect()

        async def poll(hub: SensorHub) -> None:
            end = loop.time() + seconds
            while loop.time() < end:
                hub.read_all()  # the mistake: the loop stands still meanwhile
                await asyncio.sleep(0)

        ticker = Ticker().start()
        await asyncio.gather(*(poll(h) for h in hubs))
        await ticker.stop()
    finally:
        for c in clients:
            c.close()
    return ticker


def test_eight_busy_clients_leave_the_loop_free(hub_ports: list[str]) -> None:
    ticker, counts = asyncio.run(poll_async(hub_ports, 1.5))
    assert all(n >= 3 for n in counts), counts  # every line swept, in parallel
    assert sum(counts) >= 2 * HUBS * 3  # ... at several sweeps per second each
    assert len(ticker.late) >= 50, len(ticker.late)  # ~150 ticks in 1.5 s
    assert ticker.quantile(0.99) < 0.050, ticker.summary()


def test_the_probe_sees_a_blocked_loop(hub_ports: list[str]) -> None:
    ticker = asyncio.run(poll_blocking_in_the_loop(hub_ports, 1.0))
    assert ticker.quantile(0.99) > 0.100, ticker.summary()


@pytest.mark.timing
def test_the_loop_lag_stays_under_5_ms_at_p99(hub_ports: list[str]) -> None:
    ticker, counts = asyncio.run(poll_async(hub_ports, 3.0))
    assert min(counts) >= 10, counts
    assert ticker.quantile(0.99) < 0.005, ticker.summary()
