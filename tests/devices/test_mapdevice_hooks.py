"""MapDevice's hooks for devices with habits of their own (the sensor hub's
and the CoolPro's facades are views of their maps through them): exception
04 asked again, the exception codes a read falls back on, some channels of
a block, the registers without decoding them, the planner's answer delay.
Against the scripted responder (tests/map_peers.py) and the simulator's
fault injection."""

from __future__ import annotations

import math
from array import array

import pytest
from map_peers import RefusingPtyPeer

import pymb
from pymb import maps
from pymb.devices.mapdevice import MapDevice
from pymb.errors import InvalidArgument
from pymb.maps import Buffers
from pymb.sim import SimClock, Simulator

BLOCK = """schema = "pymb.map/1"
[device]
id = "levels"
default_address = 1
table = "holding"

[device.limits]
{limits}

[[block]]
name = "levels"
first = 50
count = 6
type = "u16"
markers = {{ 0xFFFF = "offline" }}

[[block]]
name = "flows"
first = 90
count = 6
type = "u16"
"""

HAVE = {"holding": set(range(50, 56)) | set(range(90, 96))}


def level_map(limits: str = "") -> maps.Map:
    return maps.loads(BLOCK.format(limits=limits))


def peer_value(a: int) -> int:
    return (7 * a) & 0xFFFF  # tests/peers.py's holding registers


def test_some_channels_of_the_blocks_are_asked_for_and_the_rest_not_read() -> None:
    with RefusingPtyPeer(HAVE) as peer, pymb.RtuClient(peer.port, 9600, timeout=1.0) as client:
        dev = MapDevice(client, level_map("max_gap = 0"), 1)
        assert dev.plan(None, "levels", "flows", channels=[2, 3]).spans == ((51, 2), (91, 2))
        (dec,) = dev.read_into("levels", "flows", channels=[3, 2])
        assert peer.reads() == [("holding", 51, 2), ("holding", 91, 2)]
        b = dec.buffers
        for name, first in (("levels", 50), ("flows", 90)):
            slot = dec.slot(name)
            for ch in range(1, 7):
                if ch in (2, 3):
                    assert b.values[slot + ch - 1] == peer_value(first + ch - 1)
                    assert b.states[slot + ch - 1] == 0
                else:
                    assert math.isnan(b.values[slot + ch - 1])
                    assert dec.map.state_names[b.states[slot + ch - 1]] == "not_read"
        # every channel again: the values of all of them
        (dec,) = dev.read_into("levels", "flows")
        assert dec.values()["levels"] == [peer_value(a) for a in range(50, 56)]
        with pytest.raises(InvalidArgument, match=r"channel must be 1\.\.6"):
            dev.read_into("levels", channels=[7])
        with pytest.raises(InvalidArgument, match="channel numbers"):
            dev.read_into("levels", channels=3)  # type: ignore[arg-type]


def test_fetch_reads_the_registers_and_decodes_nothing() -> None:
    with RefusingPtyPeer(HAVE) as peer, pymb.RtuClient(peer.port, 9600, timeout=1.0) as client:
        dev = MapDevice(client, level_map(), 1)
        ((dec, regs),) = dev.fetch("levels")
        assert list(regs) == [peer_value(a) for a in range(50, 56)]
        assert dec.address == 50
        dec.buffers.values[0] = -1.0
        dev.fetch("levels")
        assert dec.buffers.values[0] == -1.0  # nothing decoded
        # the caller decodes them where it wants them: into its own arrays
        values, states = array("d", bytes(8 * dec.slots)), array("B", bytes(dec.slots))
        into = Buffers(dec.slots, 0, values=values, states=states)
        decode = dec.bind(regs, into)
        ((_, again),) = dev.fetch("levels")
        assert again is regs  # the same array on every read of the selection
        decode()
        assert list(values) == [float(peer_value(a)) for a in range(50, 56)]
        assert peer.reads() == [("holding", 50, 6)] * 3
        with pytest.raises(InvalidArgument, match="array"):
            Buffers(dec.slots, 0, values=array("d", bytes(8)))


def test_the_exception_codes_a_read_falls_back_on() -> None:
    # the peer answers 03 to a read of more than 4 registers
    with RefusingPtyPeer(HAVE, max_count=4) as peer, \
            pymb.RtuClient(peer.port, 9600, timeout=1.0) as client:
        only_02 = MapDevice(client, level_map(), 1, split_on=(2,))
        with pytest.raises(pymb.IllegalDataValue):
            only_02.read("levels")
        assert peer.reads() == [("holding", 50, 6)]
        both = MapDevice(client, level_map(), 1)  # 02 and 03: each channel alone
        assert both.read("levels") == {"levels": [peer_value(a) for a in range(50, 56)]}
    for bad in ((4,), "2", 2):
        with pytest.raises(InvalidArgument, match="split_on"):
            MapDevice(client, level_map(), 1, split_on=bad)  # type: ignore[arg-type]


def test_busy_answers_are_asked_again_then_raised(frozen_clock: SimClock) -> None:
    with Simulator(["hub:1"], clock=frozen_clock) as sim, \
            pymb.RtuClient(sim.port, timeout=2.0) as client:
        hub = maps.builtin("hub")
        patient = MapDevice(client, hub, 1, busy_retries=2, busy_backoff=0.001)
        sim.faults.inject("busy", count=2, address=1)
        assert len(patient.read(group="sweep")["temperature_c"]) == 100  # type: ignore[arg-type]
        assert sim.faults.counts["busy"] == 2  # type: ignore[attr-defined]
        sim.faults.inject("busy", count=3, address=1)
        with pytest.raises(pymb.DeviceFailure) as ei:
            patient.read(group="sweep")
        assert ei.value.code == 4
        sim.faults.clear()  # type: ignore[attr-defined]
        impatient = MapDevice(client, hub, 1)  # busy_retries=0: raised at once
        sim.faults.inject("busy", count=1, address=1)
        with pytest.raises(pymb.DeviceFailure):
            impatient.read(group="sweep")
        sim.faults.clear()  # type: ignore[attr-defined]
        assert impatient.read(group="sweep")["temperature_c"] is not None
    for kw in ({"busy_retries": -1}, {"busy_retries": True}, {"busy_backoff": 11},
               {"plan_turnaround": -0.1}):
        with pytest.raises(InvalidArgument):
            MapDevice(client, hub, 1, **kw)  # type: ignore[arg-type]


def test_plan_turnaround_prices_plans_and_keeps_no_silence() -> None:
    with RefusingPtyPeer(HAVE) as peer, pymb.RtuClient(peer.port, 9600, timeout=1.0) as client:
        slow = MapDevice(client, level_map("max_gap = 40"), 1, plan_turnaround=0.5)
        assert slow.plan(None, "levels", "flows").spans == ((50, 46),)  # one request, bridged
        assert slow.planner.line.turnaround == 0.5
        fast = MapDevice(client, level_map("max_gap = 40"), 1, plan_turnaround=0.0)
        assert fast.plan(None, "levels", "flows").spans == ((50, 6), (90, 6))
        slow.read("levels")
        slow.read("flows")
        first, second = peer.log
        assert second.arrived - first.replied < 0.4  # no 0.5 s silence kept


def test_whole_points_read_a_refused_request_point_by_point(frozen_clock: SimClock) -> None:
    # The hub's firmware 2.18 lacks voltage_mv, rssi_dbm and temperature2_c
    # whole: with whole_points the first sweep asks each refused request's
    # blocks apart and gives up a block refused alone (as libpymb's own hub
    # sweep does), never probing 100 channels one by one.
    with Simulator(["hub:7,firmware=2.18"], clock=frozen_clock) as sim, \
            pymb.RtuClient(sim.port, timeout=2.0) as client:
        dev = MapDevice(client, maps.builtin("hub"), 7)
        dev.planner.whole_points = True
        before = sim.stats.requests  # type: ignore[attr-defined]
        got = dev.read(group="sweep")
        first = sim.stats.requests - before  # type: ignore[attr-defined]
        # 3 good spans; 406..530 refused, then pressure_kpa's part and voltage_mv
        # alone; 531..655 refused, then rssi_dbm and temperature2_c's part alone;
        # 656..730 (temperature2_c alone) refused: libpymb's hub sweep asks as many
        assert first == 3 + 3 + 3 + 1
        for name in ("voltage_mv", "rssi_dbm", "temperature2_c"):
            assert got[name] == [None] * 100
            assert set(dev.states[name]) == {"unsupported"}
        assert "unsupported" not in dev.states["pressure_kpa"]
        before = sim.stats.requests  # type: ignore[attr-defined]
        dev.read(group="sweep")
        assert sim.stats.requests - before == 4  # type: ignore[attr-defined]


def test_whole_points_give_up_every_channel_of_a_point_refused_alone(
        frozen_clock: SimClock) -> None:
    # Firmware 1.07 serves 50 channels: a 100-channel read of each block is
    # refused, so each block is unsupported whole, also the channels an
    # earlier request of the same poll read (humidity 1..25 with 31..155's
    # split): the logger's "log it with channels=50" hint depends on it.
    with Simulator(["hub:7,firmware=1.07"], clock=frozen_clock) as sim, \
            pymb.RtuClient(sim.port, timeout=2.0) as client:
        dev = MapDevice(client, maps.builtin("hub"), 7)
        dev.planner.whole_points = True
        got = dev.read(group="sweep")
        assert all(v == [None] * 100 for v in got.values())
        assert {s for states in dev.states.values() for s in states} == {"unsupported"}
