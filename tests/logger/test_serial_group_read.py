"""A serial bus's poller reads a map device's group without decoding it
(the registers fetched, the values and states decoded on first use): the
reading is the one :meth:`MapDevice.read_group` makes, a refused point
included, over a real pseudo-terminal."""

from __future__ import annotations

from pathlib import Path

from pymb import RtuClient, maps
from pymb.devices.coolpro import coolpro_device
from pymb.devices.mapdevice import MapDevice
from pymb.devices.mapreading import MapReading
from pymb.logger.poller import _GroupRead
from pymb.sim import SimulatorProcess
from pymb.store import DeviceInfo

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
#: the logger's map has a point the served device lacks (exception 02)
LOGGED = SERVED + '''[[point]]
name = "missing_a"
address = 100
type = "f32"
'''


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
            got, want = read(), theirs.read_group(None)
            _same(got, want)
            assert got.values["missing_a"] is None
            assert got.states["missing_a"] == "unsupported"
            assert got.unsupported == ("missing_a",)
            assert got.values["voltage_v"] == 230.5


def test_a_coolpro_poll_reads_what_read_group_reads() -> None:
    info = DeviceInfo("bus", "pty", "coolpro", 40, "cp", 0, 0.1)
    with SimulatorProcess(["coolpro:40"], quiet=True) as sim, \
            RtuClient(sim.endpoint, 9600, timeout=2.0) as c:
        dev = coolpro_device(c, 40)
        read = _GroupRead(info, dev, "telemetry")
        for _ in range(2):
            got = read()
            _same(got, dev.read_group("telemetry"))
            assert got.unsupported == ()
