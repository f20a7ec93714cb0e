"""What any map's simulated device holds for a test, from the map alone:
channels set offline (blocks with an ``offline`` marker), raised flags,
identity values, the channels and points its firmware has, its register
image. A user's map, no Python of its own; read back through a real client
over Modbus TCP and through the device's request PDUs."""

from __future__ import annotations

import random
import struct

import pytest

import pymb
from pymb import maps
from pymb.devices import MapDevice
from pymb.errors import InvalidArgument
from pymb.sim import SimClock, Simulator
from pymb.sim.mapsim import MapSimDevice

MAP = """schema = "pymb.map/1"
[device]
id = "held-test"
table = "input"

[device.options]
channels = { default = 4, min = 1, max = 4 }

[groups]
fast = { interval = 1.0 }
identity = { interval = 0 }

[[block]]
name = "temp_c"
first = 10
count = "channels"
stride = 1
type = "i16"
scale = 0.1
markers = { 0x7FFF = "offline" }
example = 21.5
group = "fast"

[[block]]
name = "level"
first = 20
count = "channels"
stride = 2
type = "u32"
markers = { 0xFFFFFFFF = "offline", 0xFFFFFFFE = "no_sensor" }
example = 7
min_firmware = "2.0"
group = "fast"

[[point]]
name = "alarms"
address = 0
type = "u16"
flags = { 0 = "low", 3 = "high" }
example = 0x0100
group = "fast"

[[point]]
name = "serial_number"
address = 40
type = "u32"
group = "identity"
example = 1000

[[point]]
name = "mode"
table = "holding"
address = 0
type = "u16"
access = "rw"
flags = { 0 = "on" }
"""


def _device(**kw: object) -> tuple[MapSimDevice, SimClock]:
    clock = SimClock(0.0)
    clock.freeze()
    return MapSimDevice(maps.loads(MAP), 1, clock=clock, **kw), clock  # type: ignore[arg-type]


def _read(dev: MapSimDevice, address: int, count: int) -> list[int]:
    reply = dev.handle(struct.pack(">BHH", 4, address, count))
    assert reply is not None
    assert reply[0] == 4, reply
    return list(struct.unpack(f">{count}H", reply[2:]))


@pytest.mark.parametrize("dynamic", [True, False])
def test_a_channel_set_offline_reads_every_blocks_offline_marker_then_comes_back(
        dynamic: bool) -> None:
    dev, clock = _device(dynamic=dynamic)
    assert _read(dev, 10, 4) == [215] * 4
    dev.set_offline([2, 4])
    assert _read(dev, 10, 4) == [215, 0x7FFF, 215, 0x7FFF]
    assert _read(dev, 20, 8) == [0, 7, 0xFFFF, 0xFFFF, 0, 7, 0xFFFF, 0xFFFF]
    dev.set_offline(2, None)
    assert _read(dev, 10, 4) == [215, 215, 215, 0x7FFF]
    dev.set_offline(1, True, seconds=5.0)
    assert _read(dev, 10, 2) == [0x7FFF, 215]
    clock.advance(5.0)
    assert _read(dev, 10, 2) == [215, 215]  # back after its seconds
    dev.set_offline(range(1, 5), False)
    assert _read(dev, 10, 4) == [215] * 4
    with pytest.raises(InvalidArgument, match=r"channel must be 1\.\.4, got 5"):
        dev.set_offline(5)


def test_a_sensor_fault_ends_on_a_device_whose_values_do_not_move() -> None:
    dev, clock = _device(dynamic=False)
    normal = _read(dev, 10, 4), _read(dev, 20, 8)
    what = dev.sensor_fault(random.Random(0), 5.0, channels=[1, 2, 3, 4])
    assert "channels [1, 2, 3, 4] without a value for 5 s" in what
    assert (_read(dev, 10, 4), _read(dev, 20, 8)) != normal
    clock.advance(5.0)
    assert (_read(dev, 10, 4), _read(dev, 20, 8)) == normal


def test_raised_flags_read_over_the_points_value_until_cleared_or_expired() -> None:
    dev, clock = _device()
    assert _read(dev, 0, 1) == [0x0100]
    dev.set_flags("alarms", 0x0009)
    dev.set_flags("alarms", 0x8000, seconds=2.0)
    assert _read(dev, 0, 1) == [0x8109]
    clock.advance(2.0)
    assert _read(dev, 0, 1) == [0x0109]
    dev.clear_flags("alarms", 0x0001)
    assert _read(dev, 0, 1) == [0x0108]
    dev.clear_flags("alarms")
    assert _read(dev, 0, 1) == [0x0100]  # the point's own bits stay
    dev.set_flags("alarms", 0x0100)
    dev.clear_flags("alarms")
    assert _read(dev, 0, 1) == [0x0100]  # a bit it had already is not taken away
    with pytest.raises(InvalidArgument, match=r"alarms mask must be 1\.\.0xFFFF, got 0"):
        dev.set_flags("alarms", 0)
    with pytest.raises(InvalidArgument, match="mode is not a read-only point with flags"):
        dev.set_flags("mode", 1)
    with pytest.raises(InvalidArgument, match="serial_number is not a read-only point"):
        dev.set_flags("serial_number", 1)


def test_identity_channels_firmware_and_the_register_image_come_from_the_map() -> None:
    dev, _ = _device(firmware="1.9")
    assert dev.channels == 4
    assert dev.supports("temp_c")
    assert not dev.supports("level")
    assert not dev.supports("nope")
    assert dev.handle(struct.pack(">BHH", 4, 20, 2)) == b"\x84\x02"  # above the firmware
    dev.firmware = "2.0"
    assert dev.supports("level")
    assert _read(dev, 20, 2) == [0, 7]
    dev.set_identity(serial_number=0x12345678)
    assert _read(dev, 40, 2) == [0x1234, 0x5678]
    assert dev.raw("serial_number") == 0x12345678
    with pytest.raises(InvalidArgument, match="temp_c is not an identity point"):
        dev.set_identity(temp_c=1)
    image = dev.registers()  # the input table from its first point to its last
    assert len(image) == 42
    assert (image[10], image[41]) == (215, 0x5678)
    assert list(dev.registers(10, 2)) == [215, 215]
    assert list(dev.registers(0, 1, table="holding")) == [0]
    with pytest.raises(InvalidArgument, match="table must be one of"):
        dev.registers(table="inputs")


def test_a_client_reads_the_held_states_as_the_map_names_them() -> None:
    m = maps.loads(MAP)
    clock = SimClock(0.0)
    dev = MapSimDevice(m, 3, clock=clock)
    with Simulator([dev], transport="tcp", clock=clock) as sim, \
            pymb.TcpClient(sim.host, sim.tcp_port) as client:
        dev.set_offline(3)
        dev.set_flags("alarms", 0x0008)
        reader = MapDevice(client, m, address=3)
        values = reader.read("temp_c", "alarms")
        assert values["temp_c"] == [21.5, 21.5, None, 21.5]
        assert values["alarms"] == 0x0108


TEXT = """schema = "pymb.map/1"
[device]
id = "text-test"
table = "holding"

[[point]]
name = "label"
address = 0
type = "string"
count = 3
example = "abcd"

[[point]]
name = "swapped"
address = 3
type = "string"
count = 2
order = "BADC"
example = "wxyz"

[[point]]
name = "words"
address = 5
type = "raw"
count = 3
example = [1, 2, 3]
"""


def test_text_and_raw_points_read_and_pin_as_one_number_of_all_their_registers() -> None:
    dev = MapSimDevice(maps.loads(TEXT), 1)
    assert dev.raw("label").to_bytes(6, "big") == b"abcd\0\0"
    assert dev.raw("swapped").to_bytes(4, "big") == b"wxyz"
    assert dev.raw("words") == 0x0001_0002_0003
    dev.pin("label", int.from_bytes(b"PIN\0\0\0", "big"))
    dev.pin("swapped", int.from_bytes(b"ab\0\0", "big"))
    dev.pin("words", 0x0007_0008_0009)
    reply = dev.handle(struct.pack(">BHH", 3, 0, 8))
    assert reply == b"\x03\x10" + b"PIN\0\0\0" + b"ba\0\0" + bytes.fromhex("000700080009")
    assert dev.map.decode("swapped", struct.unpack(">2H", reply[8:12])) == "ab"
    assert dev.raw("label").to_bytes(6, "big") == b"PIN\0\0\0"
