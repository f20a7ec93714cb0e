"""The hub read as a map device (``DeviceConfig.open``, what ``pymb log``,
``read`` and ``watch`` use) against the hub's typed view: the same values
and states from the same registers, a humidity unit per channel included,
and the blocks a firmware lacks named as the view names them."""

from __future__ import annotations

from array import array

import pytest

import pymb
from pymb.devices import SensorHub, decode_hub
from pymb.devices.deviceconfig import DeviceConfig
from pymb.devices.hubreading import BLOCKS, HUB_REGISTERS
from pymb.devices.readings import map_reading, reading_dict
from pymb.sim import Simulator


@pytest.mark.parametrize("firmware", ["1.07", "2.18", "2.23"])
def test_a_sweep_as_a_map_reading_is_the_views_reading(firmware: str) -> None:
    channels = 50 if firmware == "1.07" else 100
    units = tuple([1.0, 0.1] * (channels // 2))  # a unit a channel, both kinds
    cfg = DeviceConfig("hub", 7, options={"channels": channels, "humidity_unit": units})
    with Simulator([f"hub:7,firmware={firmware}"], seed=3) as sim, \
            pymb.RtuClient(sim.port, 9600, timeout=1.0) as c:
        _, read = cfg.open(c)
        got = read("sweep")
        hub = cfg.sweep_reader(c)
        hub("sweep")  # what the firmware lacks is learnt by a sweep, and kept
        few = hub.blocks(["humidity_pct"], [2, 3])
        view = SensorHub(c, 7, channels, list(units)).read_all()
    # the same registers decode to the same reading through the view's decoder
    regs = array("H", got.registers) + array("H", bytes(2 * (HUB_REGISTERS - len(got.registers))))
    want = decode_hub(regs, list(units), channels=channels, unsupported=got.unsupported)
    assert got.values == map_reading(want).values
    assert got.states == map_reading(want).states
    assert reading_dict(got) == reading_dict(want)
    # the blocks the firmware lacks, as the view found them
    assert set(got.unsupported) == view.unsupported
    assert (firmware == "2.23") == (not got.unsupported)
    assert list(got.values) == [b.name for b in BLOCKS]
    # a few channels of one block: every block there, the rest not read
    assert few.states["humidity_pct"][0] == "not_read"
    assert few.states["humidity_pct"][1] != "not_read"
    assert few.states["temperature_c"] == ["not_read"] * channels
    assert set(few.unsupported) == view.unsupported
