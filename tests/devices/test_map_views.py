"""A map names the typed view it is read through (``[device] view``):
``DeviceConfig.open`` builds the device the view says (the hub's sweep
reader, the CoolPro's device) and a reading's JSON takes the view's form,
by that attribute of the map, not by its id. Against simulated devices on
a pty."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator

import pytest

from pymb import RtuClient, maps
from pymb.devices.deviceconfig import DeviceConfig, MapText, shipped
from pymb.devices.hubsweep import SweepReader
from pymb.devices.readings import has_own_view, reading_dict
from pymb.maps import MapError
from pymb.maps.point import VIEWS
from pymb.sim import Simulator


@pytest.fixture(scope="module")
def sim() -> Iterator[Simulator]:
    with Simulator(["coolpro", "hub:250"]) as s:
        yield s


def _without_view(kind: str) -> MapText:
    """The shipped map of ``kind`` as a map of the same registers naming no view."""
    src = shipped(kind)
    m = src.map
    return MapText(dataclasses.replace(m, device=dataclasses.replace(m.device, view="")),
                   src.text)


def test_the_shipped_maps_of_the_views_name_them() -> None:
    assert VIEWS == ("coolpro", "hub")
    for kind in maps.builtin_ids():
        assert maps.builtin(kind).device.view == (kind if kind in VIEWS else ""), kind
    assert maps.builtin("hub").configure(channels=50).device.view == "hub"


def test_a_view_is_named_by_its_own_map_only() -> None:
    head = 'schema = "pymb.map/1"\n[device]\n'
    with pytest.raises(MapError) as e:
        maps.loads(head + 'id = "my-hub"\nview = "hub"\n', source="x.toml")
    assert str(e.value) == ("x.toml: key 'view': view 'hub' is pymb's view of its own map "
                            "(id 'hub'): a map of id 'my-hub' cannot name it; delete its view "
                            "line to read it as a plain map")
    with pytest.raises(MapError, match=r"view must be one of coolpro, hub, got 'hubb'; "
                                       r"did you mean 'hub'\?"):
        maps.loads(head + 'id = "hubb"\nview = "hubb"\n', source="x.toml")
    with pytest.raises(MapError, match="view must be a string"):
        maps.loads(head + 'id = "hub"\nview = 1\n', source="x.toml")


def test_open_builds_the_device_its_map_names(sim: Simulator) -> None:
    with RtuClient(sim.port, 9600, timeout=1.0) as client:
        # the CoolPro's view: no silence kept after a reply, exceptions as sent
        dev, read = DeviceConfig("coolpro").open(client)
        assert dev.map.timing.turnaround == 0.0
        assert not dev.map.limits.split_on_exception
        data = read("telemetry")
        assert has_own_view(data)
        assert set(reading_dict(data)) == {"values", "status_flags"}
        plain, read = DeviceConfig(_without_view("coolpro")).open(client)
        assert plain.map.timing.turnaround == 0.008
        assert plain.map.limits.split_on_exception
        data = read("telemetry")
        assert not has_own_view(data)
        assert set(reading_dict(data)) == {"values", "states", "group", "unsupported"}
        # the hub's view: its sweep reader (busy retries, firmware rules, units)
        hub, read = DeviceConfig("hub", 250).open(client)
        assert isinstance(read, SweepReader)
        assert read.device is hub
        assert hub.map.timing.response_timeout is None  # the client's
        assert set(reading_dict(read("sweep"))) == {"values", "states", "unsupported"}
        plain, read = DeviceConfig(_without_view("hub"), 250).open(client)
        assert not isinstance(read, SweepReader)
        assert plain.map.timing.response_timeout == 0.8
        assert reading_dict(read("sweep"))["group"] == "sweep"

