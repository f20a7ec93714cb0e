"""AsyncMapDevice: a device from its map, awaited, against the simulated
CoolPro over a pseudo-terminal (the shipped map) and pymodbus's sparse
server over TCP (a map of this test's own)."""

from __future__ import annotations

import asyncio
from collections.abc import Callable

import pytest

import pymb
from pymb import maps
from pymb.aio import AsyncCoolPro, AsyncMapDevice, AsyncRtuClient, AsyncTcpClient
from pymb.sim import Simulator

pytest_plugins = ["pymb.testing"]

SPARSE_MAP = """schema = "pymb.map/1"
[device]
id = "sparse"
default_address = 5
table = "holding"

[groups]
fast = { interval = 1.0 }

[[point]]
name = "a"
address = 0
type = "u16"
group = "fast"

[[point]]
name = "c"
address = 3
type = "u32"
group = "fast"

[[point]]
name = "g"
address = 22
type = "u16"
group = "fast"
"""


def test_the_shipped_coolpro_map_read_and_written(
        pymb_simulator: Callable[..., Simulator]) -> None:
    sim = pymb_simulator("coolpro:40,serial=0x00C0FFEE")

    async def main() -> None:
        async with AsyncRtuClient(sim.port, 9600, timeout=1.0) as c:
            meter = AsyncMapDevice(c, maps.builtin("coolpro"), 40)
            cp = AsyncCoolPro(c, 40)
            tele, ident, serial = await asyncio.gather(
                meter.read(group="telemetry"), cp.read_identity(), meter.read("serial_number"))
            assert 20 < tele["input_voltage_v"] < 30  # type: ignore[operator]
            assert set(meter.states) == {"serial_number"}  # the last read to finish
            assert serial == {"serial_number": ident.serial_number} == \
                {"serial_number": 0x00C0FFEE}
            assert [list(r) for r in meter.plan("telemetry").spans] == [[0, 8]]
            await meter.write("address", 41)
            assert (await meter.read("address")) == {"address": 41}
            with pytest.raises(pymb.InvalidArgument):
                await meter.write("address", 300)  # refused before any byte is sent
            with pytest.raises(pymb.InvalidArgument, match="no group"):
                await meter.read(group="fastest")
            kept = await meter.read_group("telemetry")  # as the logger keeps it
            assert set(kept.values) == set(tele)
            assert len(kept.registers) == 8
            polled = []
            async for values in meter.poll(0, group="telemetry"):
                polled.append(values)
                if len(polled) == 3:
                    break
            assert all(set(v) == set(tele) for v in polled)

    asyncio.run(main())


def test_against_pymodbus_that_lacks_a_register() -> None:
    pytest.importorskip("pymodbus")
    from map_peers import sparse_pymodbus

    async def main(port: int) -> None:
        async with AsyncTcpClient("127.0.0.1", port, timeout=2.0) as c:
            meter = AsyncMapDevice(c, maps.loads(SPARSE_MAP), baudrate=9600)
            assert meter.address == 5
            got = await meter.read(group="fast")
            assert got == {"a": 100, "c": (103 << 16) | 104, "g": None}
            assert meter.states["g"] == "unsupported"

    spec = {"holding": {0: 100, 1: 101, 3: 103, 4: 104}}
    with sparse_pymodbus("tcp", spec) as server:
        asyncio.run(main(server.port))
