"""The simulated map device on its own (request PDUs in, reply PDUs out, a
frozen clock): declared registers only, examples, the seeded model, writes
of whole writable points, the sensor fault."""

from __future__ import annotations

import random
import re
import struct

import pytest

from pymb import maps
from pymb.errors import InvalidArgument
from pymb.sim import SimClock
from pymb.sim.mapsim import MapSimDevice

MAP = """schema = "pymb.map/1"
[device]
id = "sim-test"
table = "holding"
[device.limits]
readable = { holding = [[100, 103]] }

[[point]]
name = "level"
address = 0
type = "u16"
scale = 0.1
valid = [0.0, 50.0]

[[point]]
name = "total"
address = 1
type = "u32"
kind = "counter"

[[point]]
name = "setpoint"
address = 3
type = "f32"
access = "rw"
example = 12.5

[[point]]
name = "probe_c"
address = 5
type = "i16"
scale = 0.1
markers = { 0x8000 = "offline" }
example = 21.5
"""


def read(dev: MapSimDevice, address: int, count: int) -> list[int] | int:
    reply = dev.handle(struct.pack(">BHH", 3, address, count))
    assert reply is not None
    if reply[0] & 0x80:
        return reply[1]
    return list(struct.unpack(f">{count}H", reply[2:]))


def regs(dev: MapSimDevice, address: int, count: int) -> list[int]:
    got = read(dev, address, count)
    assert isinstance(got, list), got
    return got


def device(seed: int = 1) -> tuple[MapSimDevice, SimClock]:
    clock = SimClock(start=100.0)
    clock.freeze()
    return MapSimDevice(maps.loads(MAP), 1, seed=seed, clock=clock), clock


def test_only_declared_and_readable_registers_exist() -> None:
    dev, _ = device()
    assert isinstance(read(dev, 0, 6), list)
    assert read(dev, 0, 7) == 2  # 6 is not declared
    assert read(dev, 100, 4) == [0, 0, 0, 0]  # readable: zeros
    assert read(dev, 99, 2) == 2
    assert read(dev, 0, 126) == 3


def test_examples_and_a_seeded_model_that_moves_with_the_clock() -> None:
    dev, clock = device()
    m = dev.map
    assert m.decode("setpoint", regs(dev, 3, 2)) == 12.5
    assert m.decode("probe_c", regs(dev, 5, 1)) == 21.5
    level0 = m.decode("level", regs(dev, 0, 1))
    total0 = m.decode("total", regs(dev, 1, 2))
    assert isinstance(level0, float)
    assert 0.0 <= level0 <= 50.0
    clock.advance(20.0)
    level1 = m.decode("level", regs(dev, 0, 1))
    total1 = m.decode("total", regs(dev, 1, 2))
    assert level1 != level0
    assert isinstance(level1, float)
    assert 0.0 <= level1 <= 50.0
    assert isinstance(total0, int)
    assert isinstance(total1, int)
    assert total1 > total0  # a counter counts up
    # the same seed, the same values; another seed, others
    again, c2 = device()
    c2.advance(20.0)
    assert read(again, 0, 3) == read(dev, 0, 3)
    other, c3 = device(seed=2)
    c3.advance(20.0)
    assert read(other, 0, 3) != read(dev, 0, 3)


def test_writes_must_cover_whole_writable_points() -> None:
    dev, clock = device()
    assert dev.handle(struct.pack(">BHH", 6, 3, 0x4148)) == bytes((0x86, 2))  # half a float
    assert dev.handle(struct.pack(">BHH", 6, 0, 5)) == bytes((0x86, 2))  # read-only
    words = dev.map.encode("setpoint", 49.5)
    pdu = struct.pack(">BHHB2H", 16, 3, 2, 4, *words)
    assert dev.handle(pdu) == pdu[:5]
    clock.advance(60.0)
    assert dev.map.decode("setpoint", regs(dev, 3, 2)) == 49.5


def test_the_sensor_fault_shows_a_marker_then_goes() -> None:
    dev, clock = device()
    rng = random.Random(0)
    what = dev.sensor_fault(rng, 5.0)
    assert "without a value" in what
    name = what.split()[0]
    p = dev.map.points[name]
    value, state = dev.map.decode_state(name, regs(dev, p.address, p.count))
    assert value is None
    assert state in ("offline", "nan")
    clock.advance(5.0)
    assert dev.map.decode_state(name, regs(dev, p.address, p.count))[1] == "value"


def test_the_device_syntax_of_a_simulated_map_device() -> None:
    from pymb.sim.simulator import map_sim_device

    known = {"sim-test": maps.loads(MAP)}
    dev = map_sim_device("sim-test:9,delay=0.25,dynamic=0,baud=19200", known)
    assert dev is not None
    assert (dev.address, dev.turnaround(), dev.dynamic, dev.baud) == (9, 0.25, False, 19200)
    assert map_sim_device("coolpro", known) is None
    with pytest.raises(InvalidArgument,
                       match=re.escape("bad value for delay: 'soon' (0..60 seconds")):
        map_sim_device("sim-test,delay=soon", known)
    with pytest.raises(InvalidArgument, match="unknown key 'delya'"):
        map_sim_device("sim-test,delya=1", known)


VIEWS = """schema = "pymb.map/1"
[device]
id = "views-test"
table = "holding"
[[point]]
name = "status"
address = 0
type = "u16"
example = 9
[[point]]
name = "fault"
address = 0
type = "bit"
bit = 0
[[point]]
name = "mode_bits"
address = 0
type = "bits"
shift = 4
width = 3
[[point]]
name = "word"
address = 1
type = "u16"
[[point]]
name = "alarm"
address = 1
type = "bit"
bit = 15
example = true
"""


@pytest.mark.parametrize("seed", range(8))
def test_an_example_wins_over_views_of_its_register_without_one(seed: int) -> None:
    dev = MapSimDevice(maps.loads(VIEWS), 1, seed=seed, clock=SimClock(0.0))
    assert read(dev, 0, 2) == [9, 0x8000]
    dev.clock.advance(10.0)
    assert read(dev, 0, 2) == [9, 0x8000]  # the model leaves them be


ENGINE = """schema = "pymb.map/1"
[device]
id = "engine-test"
table = "holding"
addresses = [1, 99]
[[point]]
name = "mode"
address = 0
type = "u16"
access = "rw"
valid = [1, 5]
example = 2
[[point]]
name = "setpoint"
address = 1
type = "u16"
scale = 0.5
access = "rw"
valid = [10.0, 20.0]
example = 15.0
[[point]]
name = "extra"
address = 2
type = "u16"
min_firmware = "2.1"
example = 7
"""


def test_writes_outside_valid_answer_03_and_broadcast_writes_are_carried_out() -> None:
    dev = MapSimDevice(maps.loads(ENGINE), 1, seed=0, clock=SimClock(0.0), dynamic=False)
    assert dev.handle(struct.pack(">BHH", 6, 0, 6)) == bytes((0x86, 3))
    assert dev.handle(struct.pack(">BHH", 6, 1, 41)) == bytes((0x86, 3))  # 20.5: above 20
    pdu = struct.pack(">BHHB2H", 16, 0, 2, 4, 3, 40)  # mode 3, setpoint 20.0
    assert dev.handle(pdu) == pdu[:5]
    assert regs(dev, 0, 2) == [3, 40]
    dev.handle_broadcast(struct.pack(">BHH", 6, 0, 5))
    assert dev.raw("mode") == 5
    dev.handle_broadcast(struct.pack(">BHH", 6, 0, 9))  # outside valid: nothing
    dev.handle_broadcast(struct.pack(">BHH", 3, 0, 1))  # a read: nothing
    assert dev.raw("mode") == 5
    with pytest.raises(InvalidArgument, match="mode"):
        dev.raw("mdoe")


def test_points_above_the_firmware_answer_02_and_the_address_is_checked() -> None:
    m = maps.loads(ENGINE)
    old = MapSimDevice(m, 1, clock=SimClock(0.0), firmware="2.0")
    assert read(old, 2, 1) == 2
    assert read(old, 0, 2) == [2, 30]
    old.firmware = "2.1"
    assert read(old, 0, 3) == [2, 30, 7]
    assert read(MapSimDevice(m, 1, clock=SimClock(0.0)), 2, 1) == [7]  # no firmware: all
    with pytest.raises(InvalidArgument, match=r"1\.\.99"):
        MapSimDevice(m, 100)
    with pytest.raises(InvalidArgument):
        old.firmware = "new"


def test_the_simulator_serves_a_shipped_map_by_its_id() -> None:
    from pymb.sim import Simulator, make_device

    dev = make_device("eastron-sdm630:3,dynamic=0", seed=1)
    assert isinstance(dev, MapSimDevice)
    assert (dev.kind, dev.address) == ("eastron-sdm630", 3)
    with pytest.raises(InvalidArgument, match="did you mean 'eastron-sdm630'"):
        make_device("eastron-sdm360")
    with Simulator(["coolpro", "eastron-sdm630:3"], transport="tcp") as sim:
        import pymb

        with pymb.TcpClient(sim.host, sim.tcp_port, slave=3, timeout=5) as c:
            volts = dev.map.decode("l1_voltage_v", c.read_input_registers(0, 2))
        assert isinstance(volts, float)
        assert [d.kind for d in sim.devices] == ["coolpro", "eastron-sdm630"]


def test_a_pin_holds_a_read_only_point_until_unpinned() -> None:
    clock = SimClock(0.0)
    clock.freeze()
    dev = MapSimDevice(maps.loads(MAP), 1, seed=2, clock=clock)
    before = read(dev, 5, 1)
    dev.pin("probe_c", 0x8000)  # offline, as the marker says
    dev.pin("total", 0x00010002)
    clock.advance(60.0)
    assert read(dev, 1, 2) == [1, 2]
    assert read(dev, 5, 1) == [0x8000]
    dev.unpin("probe_c")
    assert read(dev, 5, 1) == before
    dev.unpin()
    assert read(dev, 1, 2) != [1, 2]  # the counter counts again
    with pytest.raises(InvalidArgument, match="writable"):
        dev.pin("setpoint", 1)
    with pytest.raises(InvalidArgument, match="did you mean 'probe_c'"):
        dev.pin("probe", 1)


def test_every_simulated_device_takes_the_simulators_keys() -> None:
    """firmware, delay (seconds or LOW-HIGH), baud and dynamic, for any map;
    a value that does not parse is named with what the key takes."""
    from pymb.sim.simulator import map_sim_device

    m = maps.loads(MAP)
    known = {"sim-test": m}
    dev = map_sim_device("sim-test:4,firmware=2.1,delay=0.01-0.02", known)
    assert dev is not None
    assert (dev.firmware, dev.address) == ("2.1", 4)
    assert all(0.01 <= dev.turnaround() <= 0.02 for _ in range(20))
    with pytest.raises(InvalidArgument, match="bad value for dynamic: 'maybe'"):
        map_sim_device("sim-test,dynamic=maybe", known)
    with pytest.raises(InvalidArgument,
                       match=re.escape("sim-test takes firmware=..., delay=..., baud")):
        map_sim_device("sim-test,colour=red", known)
