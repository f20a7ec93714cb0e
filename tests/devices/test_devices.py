"""The device facades against the simulators over real pseudo-terminals:
every field of both devices, every marker, firmware profiles, busy retry,
configuration writes and the reset semantics."""

from __future__ import annotations

import dataclasses
import inspect
import math
import threading
import time
import tracemalloc
import weakref
from collections.abc import Callable, Iterator
from datetime import UTC, datetime
from pathlib import Path
from unittest import mock

import pytest
import reference as ref
from conftest import TIMEOUT

import pymb
from pymb.child import Child, pymb_argv
from pymb.devices import HUB, CoolPro, CoolProStatus, CoolProTelemetry, SensorHub, State, decode_hub
from pymb.devices.hub import ALL_BLOCKS, HubReading
from pymb.sim import CoolProDevice, SimClock, Simulator

T = max(TIMEOUT, 0.3)  # client timeout (at least 0.3 s)


@pytest.fixture
def bus(frozen_clock: SimClock) -> Iterator[Simulator]:
    with Simulator(["coolpro", "hub:1", "hub:250"], seed=11, clock=frozen_clock) as sim:
        yield sim


@pytest.fixture
def sim_client(bus: Simulator) -> Iterator[pymb.RtuClient]:
    with pymb.RtuClient(bus.port, 9600, timeout=T) as c:
        yield c


# -- CoolPro ----------------------------------------------------------------------


def test_coolpro_telemetry_every_field(bus: Simulator, sim_client: pymb.RtuClient) -> None:
    dev = bus.device(40)
    assert isinstance(dev, CoolProDevice)
    raw = {n: dev.register(n) for n in ("input_voltage_v", "input_current_a",
                                         "output_voltage_v", "output_current_a",
                                         "temperature_c")}
    t = CoolPro(sim_client).read_telemetry()
    for name, r in raw.items():
        assert getattr(t, name) == ref.milli(r)
    regs = sim_client.read_input_registers(0, 8, slave=40)
    assert t.uptime_s == ref.u32_low_word_first(regs[5], regs[6])
    assert isinstance(t.uptime_s, int)
    assert int(t.status) == regs[7]
    assert list(t.registers) == list(regs)


def test_telemetry_reads_between_whatever_changes_the_line(sim_client: pymb.RtuClient) -> None:
    # The steady read (its C call alone) is taken up again after the client's
    # own request, a new timeout and a reconnect: each read is the device's.
    cp = CoolPro(sim_client)

    def reconnect() -> None:
        sim_client.close()
        sim_client.connect()

    changes: list[Callable[[], object]] = [
        lambda: None,
        lambda: sim_client.read_input_registers(0, 8, slave=40),
        lambda: sim_client.set_timeout(T),
        reconnect,
    ]
    for change in changes:
        change()
        reads = [cp.read_telemetry() for _ in range(3)]
        regs = sim_client.read_input_registers(0, 8, slave=40)
        for t in reads:
            assert list(t.registers[:5]) == list(regs[:5])
            assert t.input_voltage_v == ref.milli(regs[0])


def test_coolpro_telemetry_is_a_whole_frozen_dataclass(sim_client: pymb.RtuClient) -> None:
    # read_telemetry sets the fields directly (no per-field __init__ call):
    # every declared field is set, the object stays frozen, and it compares
    # like one built through the constructor.
    t = CoolPro(sim_client).read_telemetry()
    names = [f.name for f in dataclasses.fields(CoolProTelemetry)]
    assert sorted(vars(t)) == sorted(names)
    with pytest.raises(dataclasses.FrozenInstanceError):
        t.uptime_s = 0  # type: ignore[misc]
    same = CoolProTelemetry(*(getattr(t, n) for n in names))
    assert same == t
    assert repr(same) == repr(t)


def test_read_telemetry_stays_a_method(sim_client: pymb.RtuClient) -> None:
    # a subclass's override runs at every call; a test that patches the
    # class reaches an instance that has read before; a bound method
    seen: list[CoolProTelemetry] = []

    class Logged(CoolPro):
        def read_telemetry(self) -> CoolProTelemetry:
            t = super().read_telemetry()
            seen.append(t)
            return t

    cp = Logged(sim_client)
    for _ in range(3):
        cp.read_telemetry()
    assert len(seen) == 3
    plain = CoolPro(sim_client)
    real = plain.read_telemetry()
    with mock.patch.object(CoolPro, "read_telemetry", return_value=real) as patched:
        plain.read_telemetry()
    assert patched.call_count == 1
    assert inspect.ismethod(plain.read_telemetry)
    assert weakref.WeakMethod(plain.read_telemetry)() is not None
    assert plain.read_telemetry().registers is not real.registers


def test_all_blocks_mask_is_every_block_of_the_map() -> None:
    mask = (1 << len(HUB.points)) - 1
    assert mask == ALL_BLOCKS


def test_coolpro_documented_values_and_reserved_bits(bus: Simulator,
                                                     sim_client: pymb.RtuClient) -> None:
    dev = bus.device(40)
    bus.clock.advance(30.0)  # past the startup flag
    # [CP] ch. 02 / 04: 24.5 V, 3.25 A, 24.0 V, 3.20 A, 25.8 degC; uptime 70000 s.
    for name, raw in [("input_voltage_v", 0x5FB4), ("input_current_a", 0x0CB2),
                      ("output_voltage_v", 0x5DC0), ("output_current_a", 0x0C80),
                      ("temperature_c", 0x64C8)]:
        dev.pin(name, raw)  # type: ignore[attr-defined]
    dev.set_status(0x8044)  # type: ignore[attr-defined]  # reserved bit 15 + two faults
    t = CoolPro(sim_client).read_telemetry()
    assert (t.input_voltage_v, t.input_current_a, t.output_voltage_v, t.output_current_a,
            t.temperature_c) == (24.5, 3.25, 24.0, 3.2, 25.8)
    assert CoolProStatus.INPUT_MEASUREMENT_FAULT in t.status
    assert CoolProStatus.TEMPERATURE_SENSOR_FAULT in t.status
    assert t.status.reserved == 0x8000
    assert int(t.status) == 0x8044


def test_coolpro_identity(bus: Simulator, sim_client: pymb.RtuClient) -> None:
    dev = bus.device(40)
    dev.set_identity(serial_number=12345, hardware_revision=3, firmware_major=1,  # type: ignore[attr-defined]
                     firmware_minor=2, firmware_patch=7, manufactured=1780000000)
    i = CoolPro(sim_client).read_identity()
    assert i.serial_number == 12345
    assert i.hardware_revision == 3
    assert i.firmware_version == "1.2.7"
    assert i.manufactured == datetime.fromtimestamp(1780000000, UTC)
    assert i.manufactured.tzinfo is UTC


def test_coolpro_config_writes_take_effect_after_reset(bus: Simulator,
                                                       sim_client: pymb.RtuClient) -> None:
    cp = CoolPro(sim_client, 40)
    c = cp.read_config()
    assert (c.address, c.baud_rate, c.baud_rate_index) == (40, 9600, 0)
    cp.set_address(42)
    cp.set_baud_rate(9600)
    assert cp.read_config().address == 42  # stored...
    assert cp.address == 40  # ...but the device still answers at 40
    assert sim_client.read_holding_registers(2, 1, slave=40)[0] == 0  # reset reads 0
    before = cp.read_telemetry().uptime_s
    bus.clock.advance(5.0)
    assert cp.read_telemetry().uptime_s >= before + 5
    cp.reset()
    assert cp.address == 42
    t = cp.read_telemetry()
    assert t.uptime_s < 2
    assert CoolProStatus.SYSTEM_STARTUP in t.status
    with pytest.raises(pymb.ModbusTimeout):
        sim_client.read_input_registers(0, 1, slave=40)
    bus.clock.advance(10.0)
    assert CoolProStatus.SYSTEM_STARTUP not in cp.read_telemetry().status


def test_coolpro_writes_validated_before_any_io(bus: Simulator, sim_client: pymb.RtuClient) -> None:
    cp = CoolPro(sim_client, 40)
    served = bus.stats.requests  # type: ignore[attr-defined]
    for bad in (lambda: cp.set_address(0), lambda: cp.set_address(248),
                lambda: cp.set_baud_rate(14400), lambda: CoolPro(sim_client, 250)):
        with pytest.raises(pymb.InvalidArgument):
            bad()
    assert bus.stats.requests == served  # type: ignore[attr-defined]


def test_coolpro_exception_codes(sim_client: pymb.RtuClient) -> None:
    with pytest.raises(pymb.IllegalDataAddress):
        sim_client.read_input_registers(6, 4, slave=40)  # runs past the end of the block
    with pytest.raises(pymb.IllegalDataAddress):
        sim_client.read_input_registers(50, 1, slave=40)
    with pytest.raises(pymb.IllegalDataValue):
        sim_client.write_register(0, 248, slave=40)
    with pytest.raises(pymb.IllegalDataValue):
        sim_client.write_register(1, 5, slave=40)
    with pytest.raises(pymb.IllegalDataValue):
        sim_client.write_register(2, 0x1234, slave=40)
    with pytest.raises(pymb.IllegalFunction):
        sim_client.write_registers(0, [40], slave=40)


# -- sensor hub -------------------------------------------------------------------


def assert_matches_device(r: pymb.devices.HubReading, dev: object, units: bytes) -> None:
    regs = dev.registers()  # type: ignore[attr-defined]
    assert list(r.registers) == list(regs)
    for index, name in enumerate(HUB.points):
        vals = getattr(r, name)
        for c in range(r.channels):
            _st, want = ref.hub_value(index, regs[index * 100 + c], 0.1 if units[c] else 1)
            got = vals[c]
            assert (math.isnan(got) and math.isnan(want)) or got == want, (name, c)


def test_hub_read_all_six_requests_every_value(bus: Simulator, sim_client: pymb.RtuClient) -> None:
    dev = bus.device(1)
    hub = SensorHub(sim_client, 1, humidity_unit=[0.1 if t else 1 for t in dev.humidity_tenths])  # type: ignore[attr-defined]
    served = bus.stats.requests  # type: ignore[attr-defined]
    r = hub.read_all()
    assert bus.stats.requests - served == 6  # type: ignore[attr-defined]
    assert len(r.temperature_c) == 100
    assert r.unsupported == frozenset()
    assert_matches_device(r, dev, dev.humidity_tenths)  # type: ignore[attr-defined]
    assert hub.plan().spans == ((31, 125), (156, 125), (281, 125), (406, 125), (531, 125),
                                (656, 75))


def test_hub_markers_and_units_per_channel(bus: Simulator, sim_client: pymb.RtuClient) -> None:
    dev = bus.device(250)
    dev.set_humidity_unit([1, 2], 1)  # type: ignore[attr-defined]
    dev.set_humidity_unit(range(3, 101), 0.1)  # type: ignore[attr-defined]
    dev.pin("temperature_c", 1, 0x8000)  # type: ignore[attr-defined]  # -0.0
    dev.pin("temperature_c", 2, 0x8000 | 123)  # type: ignore[attr-defined]
    dev.pin("humidity_pct", 1, 0x00FF)  # type: ignore[attr-defined]  # no humidity (1 %)
    dev.pin("humidity_pct", 2, 55)  # type: ignore[attr-defined]  # 55 %
    dev.pin("humidity_pct", 3, 0x8000)  # type: ignore[attr-defined]  # no humidity (0.1 %)
    dev.pin("humidity_pct", 4, 0x00FF)  # type: ignore[attr-defined]  # 25.5 % in 0.1 %
    dev.pin("rssi_dbm", 5, 0xFFA6)  # type: ignore[attr-defined]  # -90 dBm
    dev.set_offline(6)  # type: ignore[attr-defined]
    units = [1, 1] + [0.1] * 98
    r = SensorHub(sim_client, 250, humidity_unit=units).read_all()
    assert math.copysign(1, r.temperature_c[0]) == -1
    assert r.temperature_c[0] == 0
    assert r.temperature_c[1] == -12.3
    assert r.state("humidity_pct", 1) is State.NO_SENSOR
    assert math.isnan(r.humidity_pct[0])
    assert r.humidity_pct[1] == 55.0
    assert r.state("humidity_pct", 3) is State.NO_SENSOR
    assert r.humidity_pct[3] == 25.5
    assert r.rssi_dbm[4] == -90.0
    ch6 = r.channel(6)
    assert all(s is State.OFFLINE for s in ch6.states.values())
    assert math.isnan(ch6.temperature_c)
    assert_matches_device(r, dev, bytes(1 if u == 0.1 else 0 for u in units))


@pytest.mark.parametrize(("firmware", "channels", "missing", "requests"), [
    ("2.23", 100, set(), 6),
    ("2.19", 100, {"temperature2_c"}, 5),
    ("2.18", 100, {"voltage_mv", "rssi_dbm", "temperature2_c"}, 4),
    ("1.07", 50, {"pressure_temperature_c", "pressure_kpa", "voltage_mv", "rssi_dbm",
                  "temperature2_c"}, 2),
])
def test_hub_firmware_profiles(frozen_clock: SimClock, firmware: str, channels: int,
                               missing: set[str], requests: int) -> None:
    with Simulator([f"hub:7,firmware={firmware}"], clock=frozen_clock) as sim, \
            pymb.RtuClient(sim.port, timeout=T) as c:
        hub = SensorHub(c, 7, channels=channels)
        r = hub.read_all()  # the first sweep finds out what is missing...
        assert r.unsupported == missing
        assert hub.unsupported == missing
        for name in missing:
            assert set(r.states(name)) == {State.UNSUPPORTED}
        present = [name for name in HUB.points if name not in missing]
        for name in present:
            assert State.UNSUPPORTED not in set(r.states(name))
            assert len(getattr(r, name)) == channels
        served = sim.stats.requests  # type: ignore[attr-defined]
        r2 = hub.read_all()  # ...and the next one does not ask for it again
        assert sim.stats.requests - served == requests  # type: ignore[attr-defined]
        assert r2.unsupported == missing
        dev = sim.device(7)
        regs = dev.registers()  # type: ignore[attr-defined]
        assert list(r2.registers[:channels]) == list(regs[:channels])
        # After a reconnect the hub is probed again (it may have new firmware).
        c.close()
        c.connect()
        dev.firmware = "2.23"  # type: ignore[attr-defined]
        if channels == 100:
            assert hub.read_all().unsupported == frozenset()


def test_hub_busy_is_retried_then_raised(bus: Simulator, sim_client: pymb.RtuClient) -> None:
    bus.faults.inject("busy", count=2, address=1)
    r = SensorHub(sim_client, 1, busy_backoff=0.005).read_all()
    assert r.unsupported == frozenset()
    assert bus.faults.counts["busy"] == 2  # type: ignore[attr-defined]
    bus.faults.inject("busy", count=10, address=1)
    hub = SensorHub(sim_client, 1, busy_retries=2, busy_backoff=0.005)
    with pytest.raises(pymb.DeviceBusy) as ei:
        hub.read_all()
    assert ei.value.code == 4
    assert "busy" in str(ei.value)
    bus.faults.clear()  # type: ignore[attr-defined]
    assert len(hub.read_all().temperature_c) == 100


def test_hub_fc16_answers_illegal_function(sim_client: pymb.RtuClient) -> None:
    with pytest.raises(pymb.IllegalFunction):
        sim_client.write_registers(31, [1], slave=1)
    with pytest.raises(pymb.IllegalDataAddress):
        sim_client.read_holding_registers(725, 10, slave=1)  # past 730


def test_planned_partial_reads(bus: Simulator, sim_client: pymb.RtuClient) -> None:
    dev = bus.device(1)
    hub = SensorHub(sim_client, 1, turnaround=0.0)
    served = bus.stats.requests  # type: ignore[attr-defined]
    r = hub.read(blocks=["temperature_c", "humidity_pct"], channels=range(1, 13))
    assert bus.stats.requests - served == 2  # type: ignore[attr-defined]
    regs = dev.registers()  # type: ignore[attr-defined]
    for c in range(12):
        want = ref.sign_magnitude_tenths(regs[c])[1]
        assert r.temperature_c[c] == want or (math.isnan(want) and math.isnan(r.temperature_c[c]))
    assert r.state("temperature_c", 13) is State.NOT_READ
    assert set(r.states("pressure_kpa")) == {State.NOT_READ}
    plan = hub.plan(blocks=["temperature_c", "humidity_pct"], channels=range(1, 13))
    assert plan.spans == ((31, 12), (131, 12))
    assert "predicted" in plan.explain()


def test_sweeps_of_several_buses_run_in_parallel(frozen_clock: SimClock) -> None:
    # The GIL is released for the whole sweep: two buses at an emulated line
    # speed take about as long together as one alone.
    with Simulator(["hub"], baud=115200, clock=frozen_clock) as a, \
            Simulator(["hub"], baud=115200, clock=frozen_clock) as b, \
            pymb.RtuClient(a.port, 115200, timeout=1) as ca, \
            pymb.RtuClient(b.port, 115200, timeout=1) as cb:
        hubs = [SensorHub(ca, 1), SensorHub(cb, 1)]
        for h in hubs:
            h.read_all()
        t0 = time.monotonic()
        hubs[0].read_all()
        one = time.monotonic() - t0
        threads = [threading.Thread(target=h.read_all) for h in hubs]
        t0 = time.monotonic()
        for t in threads:
            t.start()
        for t in threads:
            t.join(10)
        two = time.monotonic() - t0
        assert two < 1.6 * one, (one, two)


def test_decode_hub_of_a_device_image(bus: Simulator) -> None:
    dev = bus.device(1)
    r = decode_hub(dev.registers(), [0.1 if t else 1 for t in dev.humidity_tenths])  # type: ignore[attr-defined]
    assert_matches_device(r, dev, dev.humidity_tenths)  # type: ignore[attr-defined]


def test_one_hub_shared_by_threads(bus: Simulator, sim_client: pymb.RtuClient) -> None:
    dev = bus.device(1)
    hub = SensorHub(sim_client, 1, humidity_unit=[0.1 if t else 1 for t in dev.humidity_tenths])  # type: ignore[attr-defined]
    errors: list[BaseException] = []

    def worker() -> None:
        try:
            for _ in range(10):
                assert_matches_device(hub.read_all(), dev, dev.humidity_tenths)  # type: ignore[attr-defined]
        except BaseException as e:  # pragma: no cover - reported below
            errors.append(e)

    threads = [threading.Thread(target=worker) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    assert errors == []


def test_read_all_into_reuses_the_buffers(bus: Simulator, sim_client: pymb.RtuClient) -> None:
    hub = SensorHub(sim_client, 1)
    r = hub.read_all()
    values_before = r.values
    bus.device(1).pin("temperature_c", 1, 123)  # type: ignore[attr-defined]
    r2 = hub.read_all(into=r)
    assert r2 is r
    assert r.values is values_before
    assert r.temperature_c[0] == 12.3


def test_read_all_into_allocates_no_arrays(tmp_path: Path) -> None:
    # A steady read_all(into=r) allocates nothing for the sweep:
    # no arrays, no per-register objects. The simulator runs in a process of
    # its own, so that only this process's allocations are traced.
    sim = Child("simulator", pymb_argv("simulate", "--link", str(tmp_path / "hub"),
                                       "hub:1,dynamic=0"))
    try:
        sim.readline(30)
        with pymb.RtuClient(str(tmp_path / "hub"), timeout=5) as c:
            hub = SensorHub(c, 1)
            r = hub.read_all()
            hub.read_all(into=r)
            tracemalloc.start()
            try:
                before, _ = tracemalloc.get_traced_memory()
                tracemalloc.reset_peak()
                for _ in range(30):
                    assert hub.read_all(into=r) is r
                after, peak = tracemalloc.get_traced_memory()
            finally:
                tracemalloc.stop()
    finally:
        sim.stop()
    # The smallest array a sweep could make (700 registers) is 1,400 bytes.
    assert peak - before < 1024, f"a sweep allocated {peak - before} bytes at its peak"
    assert after - before < 256


def test_rs485_mode_on_a_port_without_it_is_a_clear_error(bus: Simulator) -> None:
    c = pymb.RtuClient(bus.port, serial_mode="rs485", timeout=T)
    with pytest.raises(pymb.ModbusConnectionError, match="RS485"):
        c.connect()
    assert not c.connected


def test_changed_channel_lists_are_planned_again(bus: Simulator,
                                                 sim_client: pymb.RtuClient) -> None:
    hub = SensorHub(sim_client, 1)
    chans = [1, 2]
    hub.read(blocks=["temperature_c"], channels=chans)
    chans.append(3)  # the same list object, changed
    r = hub.read(blocks=["temperature_c"], channels=chans)
    assert r.state("temperature_c", 3) is not State.NOT_READ
    assert r.state("temperature_c", 4) is State.NOT_READ


def test_a_hub_reading_is_stamped_by_the_time_module(sim_client: pymb.RtuClient) -> None:
    # a test that patches time.time / time.monotonic sees its clock in the reading
    hub = SensorHub(sim_client, 1)
    first = hub.read_all()
    reads: list[Callable[[], HubReading]] = [
        hub.read_all, lambda: hub.read_all(into=first), lambda: hub.read(["temperature_c"])]
    for read in reads:
        with mock.patch("time.time", return_value=1234.5), \
                mock.patch("time.monotonic", return_value=42.0):
            r = read()
        assert (r.time, r.monotonic) == (1234.5, 42.0)
