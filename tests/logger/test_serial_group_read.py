"""A serial bus's poller reads a map device's group without decoding it
(the registers fetched, handed to the writer as a poll of a block, the values
and states decoded on first use): the reading the writer gets is the one
:meth:`MapDevice.read_group` makes, a refused point included, over a real
pseudo-terminal. A simulated device whose values follow the simulated time
(a CoolPro, a hub) is read with its clock frozen: the two reads compared
are of the same values however far apart the load puts them."""

from __future__ import annotations

import queue
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from pymb import RtuClient, maps
from pymb.devices.coolpro import coolpro_device
from pymb.devices.deviceconfig import parse_device
from pymb.devices.mapdevice import MapDevice
from pymb.devices.mapreading import MapReading
from pymb.logger.poller import _GroupRead
from pymb.logger.report import Report
from pymb.logger.stats import Stats
from pymb.sim import Simulator, SimulatorProcess
from pymb.store import DeviceInfo
from pymb.store.block import PollBlock

SERVED = '''schema = "pymb.map/1"
[device]
id = "test-meter"
table = "input"
[[point]]
name = "voltage_v"
address = 0
type = "f32"
unit = "V"
example = 230.5
[[point]]
name = "energy_kwh"
address = 2
type = "u32"
kind = "counter"
example = 1234
'''
MakeSim = Callable[..., Simulator]
#: the logger's map has a point the served device lacks (exception 02)
LOGGED = SERVED + '''[[point]]
name = "missing_a"
address = 100
type = "f32"
'''


def _polled(read: _GroupRead) -> MapReading:
    """One read of ``read`` as the writer gets it from the poller's report."""
    report = Report(queue.Queue(), Stats())
    image, unread = read()
    report.poll(read.source, time.monotonic(), image, unread)
    (block,) = report.take()
    assert isinstance(block, PollBlock)
    sample = block.sample(0)
    assert sample.device is read.source.device
    assert isinstance(sample.data, MapReading)
    return sample.data


def _same(a: MapReading, b: MapReading) -> None:
    assert dict(a.values) == dict(b.values)
    assert dict(a.states) == dict(b.states)
    assert list(a.registers) == list(b.registers)
    assert a.unsupported == b.unsupported
    assert (a.map, a.group) == (b.map, b.group)


def test_a_serial_poll_reads_what_read_group_reads(tmp_path: Path) -> None:
    (tmp_path / "served.toml").write_text(SERVED)
    m = maps.loads(LOGGED)
    info = DeviceInfo("bus", "pty", "test-meter", 1, "meter", 0, 0.1)
    with SimulatorProcess(["--map", str(tmp_path / "served.toml"), "test-meter:1"],
                          quiet=True) as sim, RtuClient(sim.endpoint, 9600, timeout=2.0) as c:
        ours, theirs = MapDevice(c, m, 1), MapDevice(c, m, 1)
        read = _GroupRead(info, ours, None)
        # the first read is refused and taught, the next ones leave the point out
        for _ in range(3):
            got, want = _polled(read), theirs.read_group(None)
            _same(got, want)
            assert got.values["missing_a"] is None
            assert got.states["missing_a"] == "unsupported"
            assert got.unsupported == ("missing_a",)
            assert got.values["voltage_v"] == 230.5


def test_a_coolpro_poll_reads_what_read_group_reads(pymb_simulator: MakeSim) -> None:
    info = DeviceInfo("bus", "pty", "coolpro", 40, "cp", 0, 0.1)
    sim = pymb_simulator("coolpro:40")
    sim.clock.freeze()
    with RtuClient(sim.port, 9600, timeout=2.0) as c:
        dev = coolpro_device(c, 40)
        read = _GroupRead(info, dev, "telemetry")
        for _ in range(2):
            got = _polled(read)
            _same(got, dev.read_group("telemetry"))
            assert got.unsupported == ()


@pytest.mark.parametrize("served", ["hub:7", "hub:7,firmware=1.07"])
def test_a_hub_sweep_polled_as_its_group_reads_what_the_sweep_reader_reads(
        served: str, pymb_simulator: MakeSim) -> None:
    """A hub of one humidity unit is polled as its map's group: the writer's
    reading is the hub's own (:class:`SweepReader`), the blocks its firmware
    lacks included (refused, then left out), over a real pseudo-terminal."""
    cfg = parse_device("hub:7,channels=50")
    info = DeviceInfo("bus", "pty", "hub", 7, "hub", 50, 0.1)
    sim = pymb_simulator(served)
    sim.clock.freeze()
    with RtuClient(sim.port, 9600, timeout=2.0) as c:
        ours, _ = cfg.open(c)
        theirs = cfg.sweep_reader(c)
        assert not theirs.mixed
        read = _GroupRead(info, ours, "sweep", theirs.busy)
        for _ in range(3):
            got, want = _polled(read), theirs("sweep")
            _same(got, want)
        assert ("firmware" in served) == bool(got.unsupported)
