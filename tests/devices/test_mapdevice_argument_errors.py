"""Every argument mistake through ``MapDevice``, ``Map`` and the
``pymb.maps`` functions is a ``pymb.InvalidArgument`` or a ``MapError`` (both
a ``pymb.ModbusError`` and a ``ValueError``), raised before anything is sent:
never a KeyError, TypeError or AttributeError from inside. One case per
method and argument."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any

import pytest

import pymb
from pymb import maps
from pymb.devices import MapDevice
from pymb.sim import Simulator

COOLPRO = maps.builtin("coolpro")
HUB = maps.builtin("hub")
Case = Callable[[pymb.RtuClient], Any]


def _meter(c: pymb.RtuClient) -> MapDevice:
    return MapDevice(c, COOLPRO, 40)


def _hub(c: pymb.RtuClient) -> MapDevice:
    return MapDevice(c, HUB, 1)


CASES: dict[str, Case] = {
    "MapDevice: no client": lambda c: MapDevice(None, COOLPRO, 40),  # type: ignore[arg-type]
    "MapDevice: a map's name, not a map": lambda c: MapDevice(c, "coolpro", 40),  # type: ignore[arg-type]
    "MapDevice: address as text": lambda c: MapDevice(c, COOLPRO, "40"),  # type: ignore[arg-type]
    "MapDevice: address 0": lambda c: MapDevice(c, COOLPRO, 0),
    "MapDevice: options as a list": lambda c: MapDevice(c, HUB, 1, options=[1]),  # type: ignore[arg-type]
    "MapDevice: an unknown option": lambda c: MapDevice(c, HUB, 1, options={"nope": 1}),
    "MapDevice: an option as bad text": lambda c: MapDevice(c, HUB, 1, options={"channels": "x"}),
    "MapDevice: an option None": lambda c: MapDevice(c, HUB, 1, options={"channels": None}),
    "MapDevice: baudrate as text": lambda c: MapDevice(c, COOLPRO, 40, baudrate="x"),  # type: ignore[arg-type]
    "MapDevice: baudrate -5": lambda c: MapDevice(c, COOLPRO, 40, baudrate=-5),
    "MapDevice.read: an unknown point": lambda c: _meter(c).read("nope"),
    "MapDevice.read: a point name as a number": lambda c: _meter(c).read(5),  # type: ignore[arg-type]
    "MapDevice.read: a point name None": lambda c: _meter(c).read(None),  # type: ignore[arg-type]
    "MapDevice.read: a point name as a list": lambda c: _meter(c).read(["a"]),  # type: ignore[arg-type]
    "MapDevice.read: an unknown group": lambda c: _meter(c).read(group="nope"),
    "MapDevice.read: a group as a number": lambda c: _meter(c).read(group=5),  # type: ignore[arg-type]
    "MapDevice.read: a group as a list": lambda c: _meter(c).read(group=["a"]),  # type: ignore[arg-type]
    "MapDevice.read: names and a group": lambda c: _meter(c).read("status", group="fast"),
    "MapDevice.read_into: a point name as a number": lambda c: _meter(c).read_into(5),  # type: ignore[arg-type]
    "MapDevice.read_group: a number": lambda c: _meter(c).read_group(5),  # type: ignore[arg-type]
    "MapDevice.read_group: an unknown group": lambda c: _meter(c).read_group("nope"),
    "MapDevice.plan: an unknown group": lambda c: _meter(c).plan("nope"),
    "MapDevice.plan: a group as a number": lambda c: _meter(c).plan(5),  # type: ignore[arg-type]
    "MapDevice.plan: a point name as a number": lambda c: _meter(c).plan(None, 5),  # type: ignore[arg-type]
    "MapDevice.write: an unknown point": lambda c: _meter(c).write("nope", 1),
    "MapDevice.write: a point name as a number": lambda c: _meter(c).write(5, 1),  # type: ignore[arg-type]
    "MapDevice.write: a read-only point": lambda c: _meter(c).write("status", 1),
    "MapDevice.write: text to a number": lambda c: _meter(c).write("address", "x"),
    "MapDevice.write: None": lambda c: _meter(c).write("address", None),
    "MapDevice.write: a list to one register": lambda c: _meter(c).write("address", [1]),
    "MapDevice.write: a channel to a point": lambda c: _meter(c).write("address", 1, channel=1),
    "MapDevice.write: a channel as text": lambda c: _hub(c).write("temperature_c", 1, channel="x"),  # type: ignore[arg-type]
    "MapDevice.write: channel 0": lambda c: _hub(c).write("temperature_c", 1, channel=0),
    "Map.point: a number": lambda c: COOLPRO.point(5),  # type: ignore[arg-type]
    "Map.decode: an unknown point": lambda c: COOLPRO.decode("nope", [0]),
    "Map.decode: no registers": lambda c: COOLPRO.decode("status", []),
    "Map.decode: registers as text": lambda c: COOLPRO.decode("status", ["a"]),  # type: ignore[list-item]
    "Map.decode_state: registers as text": lambda c: COOLPRO.decode_state("status", ["a"]),  # type: ignore[list-item]
    "Map.encode: text to a number": lambda c: COOLPRO.encode("address", "x"),
    "Map.configure: an unknown option": lambda c: HUB.configure(nope=1),
    "Map.configure: options as a list": lambda c: HUB.configure([1]),  # type: ignore[arg-type]
    "Map.plan: an unknown group": lambda c: COOLPRO.plan("nope"),
    "Map.plan: a group as a number": lambda c: COOLPRO.plan(5),  # type: ignore[arg-type]
    "Map.plan: baudrate as text": lambda c: COOLPRO.plan(None, baudrate="x"),  # type: ignore[arg-type]
    "Map.plan: baudrate 0": lambda c: COOLPRO.plan(None, baudrate=0),
    "Map.label: an unknown point": lambda c: COOLPRO.label("nope", 1),
    "Map.flag_names: a value as text": lambda c: COOLPRO.flag_names("status", "x"),  # type: ignore[arg-type]
    "maps.builtin: an unknown id": lambda c: maps.builtin("nope"),
    "maps.builtin: a number": lambda c: maps.builtin(5),  # type: ignore[arg-type]
    "maps.builtin: a list": lambda c: maps.builtin(["coolpro"]),  # type: ignore[arg-type]
    "maps.load: a number": lambda c: maps.load(5),  # type: ignore[arg-type]
    "maps.loads: a number": lambda c: maps.loads(5),  # type: ignore[arg-type]
    "maps.loads: bytes": lambda c: maps.loads(b"x = 1"),  # type: ignore[arg-type]
    "maps.Decoder: a number, not a map": lambda c: maps.Decoder(5),  # type: ignore[arg-type]
    "maps.Decoder: an unknown point": lambda c: maps.Decoder(COOLPRO, ["nope"]),
}


@pytest.fixture(scope="module")
def client() -> Iterator[pymb.RtuClient]:
    with Simulator(["coolpro", "hub:1"], seed=1) as sim, \
            pymb.RtuClient(sim.port, 9600, timeout=0.5) as c:
        yield c


@pytest.mark.parametrize("case", list(CASES))
def test_an_argument_mistake_is_a_modbus_error_and_a_value_error(
        client: pymb.RtuClient, case: str) -> None:
    before = client.connections
    with pytest.raises(pymb.ModbusError) as caught:
        CASES[case](client)
    assert isinstance(caught.value, ValueError)
    assert client.connections == before
