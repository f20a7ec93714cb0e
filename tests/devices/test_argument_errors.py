"""Every argument mistake through the facades is a ``pymb.InvalidArgument``
(a ``pymb.ModbusError`` and a ``ValueError``), raised before anything is
sent: never a KeyError, TypeError or AttributeError from inside. One case per
facade method and argument."""

from __future__ import annotations

import math
from array import array
from collections.abc import Callable, Iterator
from typing import Any

import pytest

import pymb
from pymb.devices import CoolPro, HubReading, SensorHub, decode_hub
from pymb.sim import Simulator

Case = Callable[[pymb.RtuClient], Any]


def _hub(c: pymb.RtuClient) -> SensorHub:
    return SensorHub(c, 1)


def _reading() -> HubReading:
    return decode_hub(array("H", [0] * 700))


CASES: dict[str, Case] = {
    "SensorHub: address as text": lambda c: SensorHub(c, "1"),  # type: ignore[arg-type]
    "SensorHub: address 0": lambda c: SensorHub(c, 0),
    "SensorHub: no client": lambda c: SensorHub(None, 1),  # type: ignore[arg-type]
    "SensorHub: channels 0": lambda c: SensorHub(c, 1, 0),
    "SensorHub: channels as text": lambda c: SensorHub(c, 1, "5"),  # type: ignore[arg-type]
    "SensorHub: humidity unit 2": lambda c: SensorHub(c, 1, 100, 2),
    "SensorHub: humidity unit None": lambda c: SensorHub(c, 1, 100, None),  # type: ignore[arg-type]
    "SensorHub: one humidity unit for 100 channels": lambda c: SensorHub(c, 1, 100, [0.1]),
    "SensorHub: busy_retries as a bool": lambda c: SensorHub(c, 1, busy_retries=True),
    "SensorHub: busy_retries 1.5": lambda c: SensorHub(c, 1, busy_retries=1.5),  # type: ignore[arg-type]
    "SensorHub: busy_backoff as text": lambda c: SensorHub(c, 1, busy_backoff="x"),  # type: ignore[arg-type]
    "SensorHub: busy_backoff NaN": lambda c: SensorHub(c, 1, busy_backoff=math.nan),
    "SensorHub: turnaround as text": lambda c: SensorHub(c, 1, turnaround="x"),  # type: ignore[arg-type]
    "SensorHub: turnaround -1": lambda c: SensorHub(c, 1, turnaround=-1),
    "SensorHub.read: an unknown block": lambda c: _hub(c).read(["nope"]),
    "SensorHub.read: a block name alone": lambda c: _hub(c).read("temperature_c"),
    "SensorHub.read: blocks as a number": lambda c: _hub(c).read(5),  # type: ignore[arg-type]
    "SensorHub.read: channel 0": lambda c: _hub(c).read(None, [0]),
    "SensorHub.read: channel 101": lambda c: _hub(c).read(None, [101]),
    "SensorHub.read: channel as text": lambda c: _hub(c).read(None, ["a"]),  # type: ignore[list-item]
    "SensorHub.read: channels as a number": lambda c: _hub(c).read(None, 5),  # type: ignore[arg-type]
    "SensorHub.read: into something else": lambda c: _hub(c).read(into="x"),  # type: ignore[arg-type]
    "SensorHub.read_all: into something else": lambda c: _hub(c).read_all(into=5),  # type: ignore[arg-type]
    "SensorHub.plan: an unknown block": lambda c: _hub(c).plan(["nope"]),
    "SensorHub.plan: channel 0": lambda c: _hub(c).plan(None, [0]),
    "HubReading: channels 0": lambda c: HubReading(0),
    "HubReading: channels 500": lambda c: HubReading(500),
    "HubReading.state: an unknown block": lambda c: _reading().state("nope", 1),
    "HubReading.state: channel 0": lambda c: _reading().state("temperature_c", 0),
    "HubReading.states: an unknown block": lambda c: _reading().states("nope"),
    "HubReading.channel: channel 101": lambda c: _reading().channel(101),
    "HubReading.channel: channel as text": lambda c: _reading().channel("1"),  # type: ignore[arg-type]
    "decode_hub: 5 registers": lambda c: decode_hub(array("H", [0] * 5)),
    "decode_hub: humidity unit 3": lambda c: decode_hub(array("H", [0] * 700), 3),
    "decode_hub: an unknown unsupported block":
        lambda c: decode_hub(array("H", [0] * 700), unsupported=["nope"]),
    "CoolPro: address 0": lambda c: CoolPro(c, 0),
    "CoolPro: address as text": lambda c: CoolPro(c, "40"),  # type: ignore[arg-type]
    "CoolPro: no client": lambda c: CoolPro(None, 40),  # type: ignore[arg-type]
    "CoolPro.set_address: as text": lambda c: CoolPro(c, 40).set_address("5"),  # type: ignore[arg-type]
    "CoolPro.set_address: 300": lambda c: CoolPro(c, 40).set_address(300),
    "CoolPro.set_baud_rate: 1234": lambda c: CoolPro(c, 40).set_baud_rate(1234),
    "CoolPro.set_baud_rate: as text": lambda c: CoolPro(c, 40).set_baud_rate("9600"),  # type: ignore[arg-type]
    "CoolPro.set_baud_rate: a list": lambda c: CoolPro(c, 40).set_baud_rate([9600]),  # type: ignore[arg-type]
}


@pytest.fixture(scope="module")
def client() -> Iterator[pymb.RtuClient]:
    with Simulator(["coolpro", "hub:1"], seed=1) as sim, \
            pymb.RtuClient(sim.port, 9600, timeout=0.5) as c:
        yield c


@pytest.mark.parametrize("case", list(CASES))
def test_an_argument_mistake_is_an_invalid_argument(client: pymb.RtuClient, case: str) -> None:
    before = client.connections
    with pytest.raises(pymb.InvalidArgument) as caught:
        CASES[case](client)
    assert isinstance(caught.value, pymb.ModbusError)
    assert isinstance(caught.value, ValueError)
    assert client.connections == before
