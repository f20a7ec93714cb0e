"""The async facades against the simulated devices over a pseudo-terminal:
the same results and errors as the blocking facades, sweeps that are one
job on the line, and poll()."""

from __future__ import annotations

import asyncio
import math
from collections.abc import Callable

import pytest

import pymb
from pymb.aio import AsyncCoolPro, AsyncRtuClient, AsyncSensorHub
from pymb.devices import CoolProStatus, HubReading, State, decode_hub
from pymb.sim import Simulator

pytest_plugins = ["pymb.testing"]


def test_coolpro_reads_and_configures(pymb_simulator: Callable[..., Simulator]) -> None:
    sim = pymb_simulator("coolpro:40,serial=0x1234ABCD")

    async def main() -> None:
        async with AsyncRtuClient(sim.port, 9600, timeout=1.0) as c:
            cp = AsyncCoolPro(c, 40)
            t = await cp.read_telemetry()
            assert 20 < t.input_voltage_v < 30
            assert isinstance(t.status, CoolProStatus)
            ident = await cp.read_identity()
            assert ident.serial_number == 0x1234ABCD
            cfg = await cp.read_config()
            assert (cfg.address, cfg.baud_rate) == (40, 9600)
            await cp.set_address(41)
            assert cp.address == 40  # until the reset
            await cp.reset()
            assert cp.address == 41
            assert (await cp.read_config()).address == 41
            with pytest.raises(pymb.InvalidArgument, match="baud rate"):
                await cp.set_baud_rate(1234)
            # Told where a device is, as the blocking CoolPro can be.
            other = AsyncCoolPro(c, 40)
            with pytest.raises(pymb.InvalidArgument):
                other.address = 0
            other.address = 41
            assert (await other.read_config()).address == 41

    asyncio.run(main())


def test_hub_reads_decode_like_the_blocking_hub(
        pymb_simulator: Callable[..., Simulator]) -> None:
    sim = pymb_simulator("hub:5")

    async def main() -> None:
        async with AsyncRtuClient(sim.port, 9600, timeout=1.0) as c:
            hub = AsyncSensorHub(c, 5)
            r = await hub.read_all()
            assert isinstance(r, HubReading)
            again = decode_hub(r.registers)
            assert [math.isnan(v) for v in r.values] == [math.isnan(v) for v in again.values]
            assert [v for v in r.values if not math.isnan(v)] == \
                [v for v in again.values if not math.isnan(v)]
            part = await hub.read(["temperature_c"], [1, 2])
            assert part.state("humidity_pct", 1) == State.NOT_READ
            assert part.state("temperature_c", 3) == State.NOT_READ
            assert part.state("temperature_c", 1) != State.NOT_READ
            assert list(hub.plan(["temperature_c"], [1, 2]).spans) == [(31, 2)]
            same = await hub.read_all(into=r)
            assert same is r
            with pytest.raises(pymb.InvalidArgument, match="channel"):
                await hub.read(channels=[101])

    asyncio.run(main())


def test_old_firmware_busy_answers_and_forget_firmware(
        pymb_simulator: Callable[..., Simulator]) -> None:
    sim = pymb_simulator("hub:1,firmware=2.19")

    async def main() -> None:
        async with AsyncRtuClient(sim.port, 9600, timeout=1.0) as c:
            hub = AsyncSensorHub(c, 1, busy_retries=1, busy_backoff=0.0)
            r = await hub.read_all()
            assert hub.unsupported == r.unsupported == {"temperature2_c"}
            await hub.forget_firmware()
            assert hub.unsupported == frozenset()
            sim.faults.inject("busy", count=2, address=1)
            with pytest.raises(pymb.DeviceBusy):
                await hub.read_all()

    asyncio.run(main())


def test_poll_yields_readings_on_a_grid_and_stops_on_an_error(
        pymb_simulator: Callable[..., Simulator]) -> None:
    sim = pymb_simulator("coolpro", "hub")

    async def main() -> None:
        async with AsyncRtuClient(sim.port, 9600, timeout=0.3) as c:
            cp, hub = AsyncCoolPro(c), AsyncSensorHub(c, 1)
            loop = asyncio.get_running_loop()
            stamps = []
            async for t in cp.poll(0.05):
                stamps.append(loop.time())
                assert t.input_voltage_v > 20
                if len(stamps) == 5:
                    break
            # no faster than asked (stamps are when each read ended: one read's jitter)
            assert stamps[-1] - stamps[0] >= 3 * 0.05
            readings = []
            async for r in hub.poll(0, blocks=["temperature_c"]):
                readings.append(r)
                if len(readings) == 3:
                    break
            assert len({id(r) for r in readings}) == 3  # each one the caller's own
            assert readings[0].state("humidity_pct", 1) == State.NOT_READ
            # both facades share the line: their reads take turns on it
            both = await asyncio.gather(hub.read_all(), cp.read_telemetry(), hub.read_all())
            assert isinstance(both[1].status, CoolProStatus)
            sim.faults.inject("no_reply", count=5, address=40)
            polling = cp.poll(0)
            with pytest.raises(pymb.ModbusTimeout):
                await anext(polling)
            with pytest.raises(StopAsyncIteration):  # an error ends the iteration
                await anext(polling)

    asyncio.run(main())


def test_poll_keeps_to_its_grid_and_skips_the_slots_a_slow_read_missed() -> None:
    from pymb.aio import poll

    async def main() -> list[float]:
        loop = asyncio.get_running_loop()
        starts: list[float] = []

        async def read() -> int:
            starts.append(loop.time())
            if len(starts) == 2:
                await asyncio.sleep(0.12)  # overruns two and a half slots of 0.05
            return len(starts)

        async for n in poll(read, 0.05):
            if n == 5:
                break
        return starts

    starts = asyncio.run(main())
    t0, step = starts[0], 0.05
    assert starts[1] >= t0 + step - 1e-3
    # the next slot after 0.17 is 0.20, then 0.25, ...: no read before its slot,
    # none bunched to catch up (a late start shortens the gap to the next slot only)
    for j, start in enumerate(starts[2:]):
        assert start >= t0 + (4 + j) * step - 1e-3, (j, start - t0)
