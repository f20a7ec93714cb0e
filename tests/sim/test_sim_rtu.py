"""The simulators over real pseudo-terminals: pymb's RtuClient and a raw
master that writes and reads bytes, for what a client hides (silence, exact
frames, timing, stray bytes)."""

from __future__ import annotations

import os
import select
import struct
import termios
import time
import tty
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import pytest
from conftest import TIMEOUT, wait_until

import pymb
from pymb import _native
from pymb.sim import CoolProDevice, HubDevice, Simulator

pytest_plugins = ["pymb.testing"]

T = TIMEOUT  # client timeout where a fault makes the client wait
MakeSim = Callable[..., Simulator]


class RawMaster:
    """A master that sends bytes and reads what comes back."""

    def __init__(self, path: str, baud: int = 9600) -> None:
        self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
        tty.setraw(self.fd)
        a = termios.tcgetattr(self.fd)
        a[4] = a[5] = getattr(termios, f"B{baud}")
        termios.tcsetattr(self.fd, termios.TCSANOW, a)

    def close(self) -> None:
        os.close(self.fd)

    def send(self, frame: bytes, crc: bool = True) -> float:
        """Send ``frame``; returns the time just before it was written."""
        termios.tcflush(self.fd, termios.TCIFLUSH)
        data = _native.with_crc(frame) if crc else frame
        t = time.perf_counter()
        os.write(self.fd, data)
        return t

    def recv(self, quiet: float = 0.05, limit: float = 1.0) -> tuple[bytes, float]:
        """Bytes until ``quiet`` seconds of silence; and when the last came."""
        out = b""
        last = time.perf_counter()
        end = last + limit
        while True:
            now = time.perf_counter()
            wait = min(quiet, end - now) if out else end - now
            if wait <= 0:
                return out, last
            r, _, _ = select.select([self.fd], [], [], wait)
            if not r:
                if out:
                    return out, last
                return out, last
            out += os.read(self.fd, 512)
            last = time.perf_counter()

    def recv_exactly(self, n: int, limit: float = 10.0) -> tuple[bytes, float]:
        """``n`` bytes, however they are spread in time (a loaded machine may
        pause between them); and when the last came. Fewer only after ``limit``."""
        out = b""
        last = time.perf_counter()
        end = last + limit
        while len(out) < n:
            wait = end - time.perf_counter()
            if wait <= 0 or not select.select([self.fd], [], [], wait)[0]:
                break
            out += os.read(self.fd, n - len(out))
            last = time.perf_counter()
        return out, last

    def ask(self, frame: bytes, **kw: float) -> bytes:
        self.send(frame)
        return self.recv(**kw)[0]


@contextmanager
def raw(sim: Simulator, baud: int = 9600) -> Iterator[RawMaster]:
    m = RawMaster(sim.port, baud)
    try:
        yield m
    finally:
        m.close()


@contextmanager
def client(sim: Simulator, slave: int = 40, baud: int = 9600,
           timeout: float = T) -> Iterator[pymb.RtuClient]:
    with pymb.RtuClient(sim.port, baud, slave=slave, timeout=timeout) as c:
        yield c


def rd(fc: int, slave: int, address: int, count: int) -> bytes:
    return struct.pack(">BBHH", slave, fc, address, count)


@pytest.fixture
def bus(pymb_simulator: MakeSim) -> Simulator:
    sim = pymb_simulator("coolpro", "hub:250", "hub:1,firmware=1.07", seed=1)
    sim.clock.freeze()
    return sim


# -- what the documents show --------------------------------------------------------


def test_worked_frames_exactly(coolpro_sim: Simulator) -> None:
    cp = coolpro_sim.device(40)
    assert isinstance(cp, CoolProDevice)
    for name, raw_value in (("input_voltage_v", 24500), ("input_current_a", 3250),
                            ("output_voltage_v", 24000), ("output_current_a", 3200),
                            ("temperature_c", 25800)):
        cp.pin(name, raw_value)
    with raw(coolpro_sim) as m:
        # CP ch. 04: request 28 04 00 00 00 01 36 33, response 28 04 02 5F B4 DD 71
        m.send(bytes.fromhex("2804000000013633"), crc=False)
        assert m.recv()[0] == bytes.fromhex("2804025FB4DD71")
        assert m.ask(bytes.fromhex("280400000004")) == _native.with_crc(
            bytes.fromhex("2804085FB40CB25DC00C80"))
        assert m.ask(bytes.fromhex("280400040001")) == _native.with_crc(
            bytes.fromhex("28040264C8"))
        assert m.ask(bytes.fromhex("280400640002")) == _native.with_crc(
            bytes.fromhex("28040430390000"))
        assert m.ask(bytes.fromhex("280300000001")) == _native.with_crc(
            bytes.fromhex("2803020028"))
        assert m.ask(bytes.fromhex("280300000003")) == _native.with_crc(
            bytes.fromhex("280306002800000000"))


def test_coolpro_through_the_client(coolpro_sim: Simulator) -> None:
    with client(coolpro_sim) as c:
        vin, _iin, vout, _iout, temp, _lo, _hi, _status = c.read_input_registers(0, 8)
        assert 24_000 < vin < 25_000
        assert 23_800 < vout < 24_200
        assert temp > 0
        ident = c.read_input_registers(100, 8)
        assert ident[0] | ident[1] << 16 == 12345
        assert list(ident[3:6]) == [1, 0, 0]
        assert list(c.read_holding_registers(0, 3)) == [40, 0, 0]


def test_silence_for_another_address_bad_crc_and_broadcast(bus: Simulator) -> None:
    with raw(bus) as m:
        assert m.ask(rd(4, 41, 0, 1), limit=0.15) == b""  # nobody at 41
        frame = bytearray(_native.with_crc(rd(4, 40, 0, 1)))
        frame[-1] ^= 0x01
        m.send(bytes(frame), crc=False)
        assert m.recv(limit=0.15)[0] == b""  # bad CRC: silence
        assert m.ask(rd(3, 0, 31, 1), limit=0.15) == b""  # broadcast read
        assert m.ask(struct.pack(">BBHH", 0, 6, 0, 77), limit=0.15) == b""
        assert m.ask(rd(4, 40, 0, 1))[:3] == b"\x28\x04\x02"  # still in step
    cp = bus.device(40)
    assert isinstance(cp, CoolProDevice)
    assert cp.pending_address == 77  # the broadcast write was carried out


def test_garbage_then_a_request(coolpro_sim: Simulator) -> None:
    with raw(coolpro_sim) as m:
        m.send(b"\x00\xff\x13\x37\x28\x04", crc=False)
        assert m.recv(limit=0.1)[0] == b""
        assert m.ask(rd(4, 40, 0, 1))[:3] == b"\x28\x04\x02"


def test_unknown_function_ends_at_silence_and_answers_01(bus: Simulator) -> None:
    with raw(bus) as m:
        assert m.ask(bytes.fromhex("282B0E0100")) == _native.with_crc(b"\x28\xab\x01")
        assert m.ask(bytes.fromhex("FA2B0E0100")) == _native.with_crc(b"\xfa\xab\x01")


def _coolpro_reply_times(make: MakeSim) -> tuple[list[float], list[float]]:
    """Request-to-reply times of a CoolPro with its 8 ms gap and of one with none."""
    sim = make("coolpro", "coolpro:41,gap=0")
    with raw(sim) as m:
        slow, fast = [], []
        for _ in range(5):
            t = m.send(rd(4, 40, 0, 1))
            slow.append(m.recv(quiet=0.02)[1] - t)
            t = m.send(rd(4, 41, 0, 1))
            fast.append(m.recv(quiet=0.02)[1] - t)
    return slow, fast


def test_coolpro_waits_its_gap_and_gap_0_does_not(pymb_simulator: MakeSim) -> None:
    slow, fast = _coolpro_reply_times(pymb_simulator)
    assert min(slow) >= 0.008  # a lower bound: a loaded machine only adds to it
    assert min(fast) < min(slow)


@pytest.mark.timing
def test_coolpro_gap_is_about_8_ms(pymb_simulator: MakeSim) -> None:
    slow, fast = _coolpro_reply_times(pymb_simulator)
    assert 0.008 <= min(slow) < 0.03
    assert min(fast) < 0.005


def test_hub_response_delay(pymb_simulator: MakeSim) -> None:
    sim = pymb_simulator("hub,delay=0.12")
    with raw(sim) as m:
        t = m.send(rd(3, 1, 31, 1))
        reply, when = m.recv()
    assert reply[:2] == b"\x01\x03"
    assert 0.12 <= when - t < 0.3


def test_hub_high_addresses_and_exceptions(bus: Simulator) -> None:
    with client(bus, slave=250) as c:
        assert len(c.read_holding_registers(31, 700)) == 700  # 6 requests of <= 125
        with pytest.raises(pymb.IllegalFunction):
            c.write_registers(31, [1, 2])  # 0x90 / 01
        with pytest.raises(pymb.IllegalFunction):
            c.read_input_registers(31, 1)
        with pytest.raises(pymb.IllegalDataAddress):
            c.read_holding_registers(30, 2)
        with pytest.raises(pymb.IllegalDataAddress):
            c.read_holding_registers(721, 11)  # 731 is past the end
        # the 1.07 hub at address 1: 50 channels of temperature and humidity
        assert len(c.read_holding_registers(31, 50, slave=1)) == 50
        with pytest.raises(pymb.IllegalDataAddress):
            c.read_holding_registers(31, 51, slave=1)
        with pytest.raises(pymb.IllegalDataAddress):
            c.read_holding_registers(331, 1, slave=1)
    with raw(bus) as m:
        assert m.ask(bytes.fromhex("FA10001F000102002A")) == _native.with_crc(b"\xfa\x90\x01")


def test_coolpro_exceptions_through_the_client(coolpro_sim: Simulator) -> None:
    with client(coolpro_sim) as c:
        with pytest.raises(pymb.IllegalDataAddress):
            c.read_input_registers(6, 3)
        with pytest.raises(pymb.IllegalDataAddress):
            c.read_holding_registers(3, 1)
        with pytest.raises(pymb.IllegalDataValue):
            c.write_register(0, 0)
        with pytest.raises(pymb.IllegalDataValue):
            c.write_register(2, 1)
        with pytest.raises(pymb.IllegalFunction):
            c.write_registers(0, [41])
        with pytest.raises(pymb.IllegalFunction):
            c.read_coils(0, 1)


def test_coolpro_address_and_baud_change_at_reset(coolpro_sim: Simulator) -> None:
    sim = coolpro_sim
    with client(sim) as c:
        c.write_register(0, 42)
        c.write_register(1, 1)  # 19200
        assert list(c.read_holding_registers(0, 3)) == [42, 1, 0]  # stored, not in effect
        c.write_register(2, 0xAA55)  # echoed from 40, then reset
        with pytest.raises(pymb.ModbusTimeout):
            c.read_input_registers(0, 1)  # 9600: the device now listens at 19200
    with client(sim, slave=42, baud=19200) as c:
        with pytest.raises(pymb.ModbusTimeout):
            c.read_input_registers(0, 1, slave=40)
        lo, hi, status = c.read_input_registers(5, 3)
        assert (lo, hi) == (0, 0)
        assert status & 0x01  # uptime restarted, starting up
        assert list(c.read_holding_registers(0, 3)) == [42, 1, 0]


def test_line_speed_mismatch_is_silence(coolpro_sim: Simulator) -> None:
    with client(coolpro_sim, baud=19200) as c, pytest.raises(pymb.ModbusTimeout):
        c.read_input_registers(0, 1)


def test_device_facades_read_the_simulators(pymb_simulator: MakeSim) -> None:
    from pymb.devices.coolpro import CoolPro
    from pymb.devices.hub import SensorHub, State

    sim = pymb_simulator("coolpro", "hub:7,firmware=2.18")
    hub = sim.device(7)
    assert isinstance(hub, HubDevice)
    hub.configure(3, humidity=False, humidity_tenths=True)
    hub.set_offline(4)
    with client(sim, timeout=1.0) as c:
        t = CoolPro(c).read_telemetry()
        assert 24.0 < t.input_voltage_v < 25.0
        r = SensorHub(c, 7).read_all()
        assert r.unsupported == frozenset({"voltage_mv", "rssi_dbm", "temperature2_c"})
        assert r.state("temperature_c", 4) == State.OFFLINE
        assert r.state("humidity_pct", 3) == State.NO_SENSOR
        assert r.state("voltage_mv", 1) == State.UNSUPPORTED


# -- faults, seen by the master -------------------------------------------------------


def test_fault_no_reply_late_and_recovery(coolpro_sim: Simulator) -> None:
    f = coolpro_sim.faults
    with client(coolpro_sim) as c:
        f.inject("no_reply")
        with pytest.raises(pymb.ModbusTimeout):
            c.read_input_registers(0, 1)
        f.inject("late", delay=0.3)
        with pytest.raises(pymb.ModbusTimeout):
            c.read_input_registers(0, 1)
        assert len(c.read_input_registers(0, 8)) == 8
    assert f.counts["no_reply"] == 1
    assert f.counts["late"] == 1


def test_fault_bad_crc_wrong_address_truncate(coolpro_sim: Simulator) -> None:
    f = coolpro_sim.faults
    with client(coolpro_sim) as c:
        f.inject("bad_crc")
        with pytest.raises(pymb.ProtocolError) as e:
            c.read_input_registers(0, 1)
        assert e.value.reason == "bad CRC"
        f.inject("wrong_address")
        with pytest.raises(pymb.ProtocolError) as e:
            c.read_input_registers(0, 1)
        assert e.value.response is not None
        assert e.value.response[0] == 41
        f.inject("truncate")
        with pytest.raises((pymb.ModbusTimeout, pymb.ProtocolError)):
            c.read_input_registers(0, 8)
        assert len(c.read_input_registers(0, 8)) == 8
    assert {k: v for k, v in f.counts.items() if v} == {
        "bad_crc": 1, "wrong_address": 1, "truncate": 1}


def test_fault_stray_bytes_after_a_valid_reply(coolpro_sim: Simulator) -> None:
    coolpro_sim.faults.inject("stray", extra=b"\xde\xad")
    with raw(coolpro_sim) as m:
        reply = m.ask(rd(4, 40, 0, 1))
    assert reply[-2:] == b"\xde\xad"
    assert _native.rtu_crc_ok(reply[:-2])
    coolpro_sim.faults.inject("stray")
    with client(coolpro_sim) as c:
        c.read_input_registers(0, 1)  # the reply itself is fine
        c.read_input_registers(0, 1)  # and the next request is not confused


def test_fault_exceptions_and_busy(bus: Simulator) -> None:
    f = bus.faults
    with client(bus) as c:
        f.inject("exception", code=3, address=40)
        with pytest.raises(pymb.IllegalDataValue):
            c.read_input_registers(0, 1)
        f.inject("busy", address=250)
        with pytest.raises(pymb.DeviceException) as e:
            c.read_holding_registers(31, 1, slave=250)
        assert e.value.code == 4  # the hub's "Device is busy"
        f.inject("exception", code=6)
        with pytest.raises(pymb.DeviceBusy):
            c.read_input_registers(0, 1)


def test_fault_sensor(bus: Simulator) -> None:
    f = bus.faults
    hub = bus.device(250)
    assert isinstance(hub, HubDevice)
    hub.configure(5, present=True)
    with client(bus) as c:
        f.inject("sensor", address=40, bits=0x08, seconds=60)
        vin, _, vout, iout, *_, status = c.read_input_registers(0, 8)
        assert status & 0x08
        assert (vout, iout) == (0, 0)
        assert vin > 0
        f.inject("sensor", address=250, channels=(5,), seconds=60)
        assert c.read_holding_registers(35, 1, slave=250)[0] == 0xFFFF
        bus.clock.advance(61)
        assert c.read_holding_registers(35, 1, slave=250)[0] != 0xFFFF
        assert not c.read_input_registers(7, 1)[0] & 0x08


def test_fault_by_probability_is_counted(pymb_simulator: MakeSim) -> None:
    sim = pymb_simulator("coolpro,gap=0", seed=4, faults=["no_reply:0.3"])
    timeouts = 0
    with client(sim, timeout=0.05) as c:
        for _ in range(30):
            try:
                c.read_input_registers(0, 1)
            except pymb.ModbusTimeout:
                timeouts += 1
    assert timeouts == sim.faults.counts["no_reply"] > 0


def test_unplug_and_replug(coolpro_sim: Simulator) -> None:
    sim = coolpro_sim
    first = sim.pty_path
    with client(sim) as c:
        c.read_input_registers(0, 1)
        sim.unplug()
        assert not os.path.exists(sim.port)
        with pytest.raises(pymb.ModbusConnectionError) as e:
            c.read_input_registers(0, 1)
        assert e.value.errno is not None
        assert not c.connected
        with pytest.raises(pymb.ModbusConnectionError):
            c.read_input_registers(0, 1)  # the port is still gone
        sim.replug()
        assert os.path.realpath(sim.port) == sim.pty_path
        assert len(c.read_input_registers(0, 8)) == 8  # reconnected by itself
    assert first is not None


def test_unplug_for_a_while_and_by_fault(coolpro_sim: Simulator) -> None:
    sim = coolpro_sim
    with client(sim) as c:
        sim.faults.inject("unplug", seconds=0.3)
        with pytest.raises((pymb.ModbusTimeout, pymb.ModbusConnectionError)):
            c.read_input_registers(0, 1)  # the request that pulled the plug
        assert not sim.plugged
        wait_until(lambda: sim.plugged, "the port to come back", timeout=3)
        for _ in range(3):
            try:
                c.read_input_registers(0, 1)
                break
            except pymb.ModbusConnectionError:
                continue
        assert len(c.read_input_registers(0, 8)) == 8
    assert sim.faults.counts["unplug"] == 1


# -- wire timing -----------------------------------------------------------------------


BAUD_CASES = pytest.mark.parametrize(("baud", "spec", "request_regs"), [
    (9600, "hub", 125),
    (19200, "hub", 10),
    (115200, "coolpro", 8),
])


def _wire_times(make: MakeSim, baud: int, spec: str,
                request_regs: int) -> tuple[list[float], float]:
    """Request-to-last-byte times of three reads at ``baud``, and the wire
    time they must take at least: the request's 8 characters, the device's
    turnaround, the reply's characters."""
    sim = make(spec, baud=baud)
    dev = sim.devices[0]
    char = 10 / baud
    turnaround = max(3.5 * char if baud <= 19200 else 0.00175, dev.turnaround())
    expect = 8 * char + turnaround + (5 + 2 * request_regs) * char
    fc, first = (3, 31) if spec == "hub" else (4, 0)
    with raw(sim, baud) as m:
        times = []
        for _ in range(3):
            t = m.send(rd(fc, dev.address, first, request_regs))
            reply, last = m.recv_exactly(5 + 2 * request_regs)
            assert len(reply) == 5 + 2 * request_regs
            assert reply[:2] == bytes([dev.address, fc])
            times.append(last - t)
    return times, expect


@BAUD_CASES
def test_baud_emulation_gives_each_frame_its_wire_time(pymb_simulator: MakeSim, baud: int,
                                                       spec: str, request_regs: int) -> None:
    # A lower bound: the reply's last byte never comes before its wire time
    # (a loaded machine only adds to it).
    times, expect = _wire_times(pymb_simulator, baud, spec, request_regs)
    assert expect <= min(times), (times, expect)


@pytest.mark.timing
@BAUD_CASES
def test_baud_emulation_adds_little_to_the_wire_time(pymb_simulator: MakeSim, baud: int,
                                                     spec: str, request_regs: int) -> None:
    times, expect = _wire_times(pymb_simulator, baud, spec, request_regs)
    assert expect <= min(times) < expect + 0.015, (times, expect)


def test_service_time_is_far_below_a_millisecond(hub_sim: Simulator) -> None:
    with client(hub_sim, slave=1) as c:
        for _ in range(100):
            c.read_holding_registers(31, 125)
    assert hub_sim.stats.replies == 100
    assert hub_sim.stats.service_ns_mean < 1_000_000
