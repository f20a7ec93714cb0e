"""``--identity`` is one rule over the map: a map with an ``identity`` group
read on request says what the device is by that group, shown as its view
shows it (the CoolPro's as ``CoolPro.read_identity()`` gives it); a map
without one, or whose ``identity`` group is polled (the Carlo Gavazzi
meters'), by what identification finds (the hub's channels and firmware).
Against simulated devices on a pty."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from pymb import RtuClient, maps
from pymb.commands.read import identity_of, identity_text
from pymb.devices import CoolPro, CoolProIdentity
from pymb.devices.deviceconfig import DeviceConfig, MapText
from pymb.devices.identify import Identity
from pymb.devices.mapreading import MapReading
from pymb.sim import Simulator
from pymb.sim.mapsim import MapSimDevice

METER = """schema = "pymb.map/1"
[device]
id = "meter-with-identity"
default_address = 9
table = "holding"
[groups]
fast = { interval = 1.0 }
identity = { interval = 0, poll = "request" }
[[point]]
name = "power_w"
address = 0
type = "u16"
group = "fast"
example = 120
[[point]]
name = "serial"
address = 10
type = "u32"
group = "identity"
example = 4711
"""


@pytest.fixture(scope="module")
def sim() -> Iterator[Simulator]:
    meter = MapSimDevice(maps.loads(METER, source="meter.toml"))
    with Simulator(["coolpro", "hub:250", meter, "carlo-gavazzi-em21:21"]) as s:
        yield s


def test_the_coolpros_identity_is_its_identity_group_as_its_view_shows_it(
        sim: Simulator) -> None:
    with RtuClient(sim.port, 9600, timeout=1.0) as client:
        got = identity_of(DeviceConfig("coolpro"), client)
        assert isinstance(got, CoolProIdentity)
        assert got == CoolPro(client).read_identity()
    assert identity_text(got).splitlines()[0] == "Serial Number    12345"


def test_a_map_without_an_identity_group_is_identified(sim: Simulator) -> None:
    with RtuClient(sim.port, 9600, timeout=1.0) as client:
        got = identity_of(DeviceConfig("hub", 250), client)
    assert isinstance(got, Identity)
    assert (got.device, got.channels) == ("hub", 100)


def test_any_maps_identity_group_is_its_identity(sim: Simulator) -> None:
    dev = DeviceConfig(MapText(maps.loads(METER, source="meter.toml"), METER))
    with RtuClient(sim.port, 9600, timeout=1.0) as client:
        got = identity_of(dev, client)
    assert isinstance(got, MapReading)
    assert (got.group, got.values) == ("identity", {"serial": 4711})
    assert identity_text(got).split() == ["serial", "4711"]


def test_a_polled_identity_group_is_not_read_for_identity(sim: Simulator) -> None:
    # the EM21's identity group is polled (interval 0: once after it appears),
    # not read on request: --identity identifies the device, as it always did
    assert maps.builtin("carlo-gavazzi-em21").polled("identity") == "interval"
    with RtuClient(sim.port, 9600, timeout=1.0) as client:
        got = identity_of(DeviceConfig("carlo-gavazzi-em21", 21), client)
    assert isinstance(got, Identity)
    assert identity_text(got).startswith("Identity ")
