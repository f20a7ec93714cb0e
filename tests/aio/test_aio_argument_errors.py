"""Every argument mistake through pymb.aio's clients and facades is a
``pymb.InvalidArgument`` or another ``pymb.ModbusError`` that is also a
``ValueError`` (a map's ``MapError``), raised before anything is sent: never a
TypeError, KeyError or AttributeError from inside. One case per method and
argument; a coroutine's mistake raises when it is awaited, a ``poll``'s when
it is made."""

from __future__ import annotations

import asyncio
import inspect
from collections.abc import AsyncGenerator, Callable, Iterator
from typing import Any

import pytest

import pymb
import pymb.aio
from pymb import maps
from pymb.sim import Simulator

COOLPRO = maps.builtin("coolpro")


class Devices:
    """One async client on the simulated line and a facade of each kind on it."""

    def __init__(self, client: pymb.aio.AsyncRtuClient) -> None:
        self.client = client
        self.coolpro = pymb.aio.AsyncCoolPro(client, 40)
        self.hub = pymb.aio.AsyncSensorHub(client, 1)
        self.meter = pymb.aio.AsyncMapDevice(client, COOLPRO, 40)


Case = Callable[[Devices], Any]
_TCP = pymb.TcpClient("127.0.0.1", 1502)  # never connected: a blocking client, the wrong kind

CASES: dict[str, Case] = {
    "AsyncCoolPro: a blocking client": lambda d: pymb.aio.AsyncCoolPro(_TCP),  # type: ignore[arg-type]
    "AsyncCoolPro: no client": lambda d: pymb.aio.AsyncCoolPro(None),  # type: ignore[arg-type]
    "AsyncCoolPro: address as text": lambda d: pymb.aio.AsyncCoolPro(d.client, "40"),  # type: ignore[arg-type]
    "AsyncCoolPro.set_address: as text": lambda d: d.coolpro.set_address("5"),  # type: ignore[arg-type]
    "AsyncCoolPro.set_baud_rate: 1234": lambda d: d.coolpro.set_baud_rate(1234),
    "AsyncCoolPro.poll: interval -1": lambda d: d.coolpro.poll(-1),
    "AsyncCoolPro.poll: interval as text": lambda d: d.coolpro.poll("1"),  # type: ignore[arg-type]
    "AsyncSensorHub: a blocking client": lambda d: pymb.aio.AsyncSensorHub(_TCP, 1),  # type: ignore[arg-type]
    "AsyncSensorHub: channels as text": lambda d: pymb.aio.AsyncSensorHub(d.client, 1, "5"),  # type: ignore[arg-type]
    "AsyncSensorHub.plan: an unknown block": lambda d: d.hub.plan(["nope"]),
    "AsyncSensorHub.read: an unknown block": lambda d: d.hub.read(["nope"]),
    "AsyncSensorHub.read: channel 0": lambda d: d.hub.read(None, [0]),
    "AsyncSensorHub.poll: an unknown block": lambda d: d.hub.poll(1, ["nope"]),
    "AsyncSensorHub.poll: blocks as a number": lambda d: d.hub.poll(1, 5),  # type: ignore[arg-type]
    "AsyncSensorHub.poll: channel 101": lambda d: d.hub.poll(1, None, [101]),
    "AsyncMapDevice: a blocking client": lambda d: pymb.aio.AsyncMapDevice(_TCP, COOLPRO),  # type: ignore[arg-type]
    "AsyncMapDevice: a map's name, not a map":
        lambda d: pymb.aio.AsyncMapDevice(d.client, "coolpro"),  # type: ignore[arg-type]
    "AsyncMapDevice: options as a list":
        lambda d: pymb.aio.AsyncMapDevice(d.client, COOLPRO, options=[1]),  # type: ignore[arg-type]
    "AsyncMapDevice.plan: a point name as a number": lambda d: d.meter.plan(None, 5),  # type: ignore[arg-type]
    "AsyncMapDevice.plan: a group as a number": lambda d: d.meter.plan(5),  # type: ignore[arg-type]
    "AsyncMapDevice.read: an unknown point": lambda d: d.meter.read("nope"),
    "AsyncMapDevice.read: a point name as a number": lambda d: d.meter.read(5),  # type: ignore[arg-type]
    "AsyncMapDevice.read: a group as a list": lambda d: d.meter.read(group=["a"]),  # type: ignore[arg-type]
    "AsyncMapDevice.read_group: a number": lambda d: d.meter.read_group(5),  # type: ignore[arg-type]
    "AsyncMapDevice.read_into: a number": lambda d: d.meter.read_into(5),  # type: ignore[arg-type]
    "AsyncMapDevice.write: a point name as a number": lambda d: d.meter.write(5, 1),  # type: ignore[arg-type]
    "AsyncMapDevice.write: a read-only point": lambda d: d.meter.write("status", 1),
    "AsyncMapDevice.write: text to a number": lambda d: d.meter.write("address", "x"),
    "AsyncMapDevice.poll: a point name as a number": lambda d: d.meter.poll(1, 5),  # type: ignore[arg-type]
    "AsyncMapDevice.poll: a group as a number": lambda d: d.meter.poll(1, group=5),  # type: ignore[arg-type]
    "AsyncMapDevice.poll: an unknown point": lambda d: d.meter.poll(1, "nope"),
    "AsyncClient.run: not a function": lambda d: d.client.run(5),  # type: ignore[arg-type]
    "AsyncClient.read_holding_registers: count 0": lambda d: d.client.read_holding_registers(0, 0),
    "AsyncClient.read_holding_registers: address as text":
        lambda d: d.client.read_holding_registers("x", 1),  # type: ignore[arg-type]
    "AsyncClient.write_register: value as text": lambda d: d.client.write_register(0, "x"),  # type: ignore[arg-type]
    "AsyncClient.set_timeout: as text": lambda d: d.client.set_timeout("x"),  # type: ignore[arg-type]
    "AsyncClient.slave: as text": lambda d: setattr(d.client, "slave", "x"),
    "AsyncTcpClient: port as text": lambda d: pymb.aio.AsyncTcpClient("127.0.0.1", "x"),  # type: ignore[arg-type]
    "AsyncRtuOverTcpClient: port -1": lambda d: pymb.aio.AsyncRtuOverTcpClient("127.0.0.1", -1),
    "AsyncRtuClient: baud as text":
        lambda d: pymb.aio.AsyncRtuClient(d.client.port, "x"),  # type: ignore[arg-type]
}


@pytest.fixture(scope="module")
def port() -> Iterator[str]:
    with Simulator(["coolpro", "hub:1"], seed=1) as sim:
        yield sim.port


async def _call(case: Case, d: Devices) -> None:
    result = case(d)
    if inspect.isawaitable(result):
        await result
    elif isinstance(result, AsyncGenerator):
        await result.aclose()
        pytest.fail("the mistake was not refused when the poll was made")


async def _check(port: str, case: Case) -> None:
    async with pymb.aio.AsyncRtuClient(port, 9600, timeout=0.5) as client:
        d = Devices(client)
        before = client.connections
        with pytest.raises(pymb.ModbusError) as caught:
            await _call(case, d)
        assert isinstance(caught.value, ValueError)
        assert client.connections == before


@pytest.mark.parametrize("case", list(CASES))
def test_an_argument_mistake_is_a_modbus_error_and_a_value_error(port: str, case: str) -> None:
    asyncio.run(_check(port, CASES[case]))
