"""The device models of pymb.sim without any I/O: request PDU in, reply PDU out.

Register numbers here are the documents' own (CP-MODBUS-RTU rev 1, hub
protocol V1.5, NOTES.md), written out on purpose: the simulators derive them
from the shipped maps, and these tests check that against the documents.
"""

from __future__ import annotations

import re
import struct
from collections.abc import Callable

import pytest

from pymb.errors import InvalidArgument
from pymb.sim import Channel, CoolProDevice, Faults, HubDevice, SimClock, make_device
from pymb.sim.devices import sign_magnitude
from pymb.sim.faults import parse_fault


def req(fc: int, a: int, b: int) -> bytes:
    return struct.pack(">BHH", fc, a, b)


def answer(reply: bytes | None) -> bytes:
    """A reply the device must give (None is silence)."""
    assert reply is not None
    return reply


def regs(reply: bytes | None) -> list[int]:
    assert reply is not None
    assert reply[1] == len(reply) - 2
    return list(struct.unpack(f">{reply[1] // 2}H", reply[2:]))


@pytest.fixture
def cp(frozen_clock: SimClock) -> CoolProDevice:
    return CoolProDevice(clock=frozen_clock, uptime=100.0, dynamic=False)


@pytest.fixture
def hub(frozen_clock: SimClock) -> HubDevice:
    return HubDevice(clock=frozen_clock, dynamic=False)


# -- CoolPro -------------------------------------------------------------------------


def test_coolpro_defaults_match_the_document(cp: CoolProDevice) -> None:
    assert (cp.address, cp.baud) == (40, 9600)
    assert regs(cp.handle(req(0x03, 0, 3))) == [40, 0, 0]
    ident = regs(cp.handle(req(0x04, 100, 8)))
    assert ident[0] | ident[1] << 16 == 12345  # the document's example serial
    assert ident[3:6] == [1, 0, 0]  # firmware 1.0.0
    # option 2 of the document: each word alone
    assert regs(cp.handle(req(0x04, 100, 1))) == [0x3039]
    assert regs(cp.handle(req(0x04, 101, 1))) == [0]


def test_coolpro_telemetry_is_in_milliunits_and_plausible(cp: CoolProDevice,
                                                          frozen_clock: SimClock) -> None:
    for _ in range(50):
        frozen_clock.advance(7.3)
        vin, iin, vout, iout, temp, _up_lo, _up_hi, status = regs(cp.handle(req(0x04, 0, 8)))
        assert 24_000 < vin < 25_000  # ~24.5 V
        assert 23_800 < vout < 24_200  # ~24.0 V
        assert 1_000 < iout < 6_500
        assert iin > iout * 0.95
        assert 0 < temp <= 65_535  # m°C, never negative
        assert status & 0x7F == 0
    assert regs(cp.handle(req(0x04, 4, 1)))[0] > 20_000  # ~25.8 °C


def test_coolpro_uptime_is_32_bit_low_word_first(cp: CoolProDevice, frozen_clock: SimClock) -> None:
    frozen_clock.advance(70_000 - 100)
    assert regs(cp.handle(req(0x04, 5, 2))) == [4464, 1]  # the document's 70000 s


def test_coolpro_daily_reset_wraps_uptime_and_raises_bit_1(cp: CoolProDevice,
                                                           frozen_clock: SimClock) -> None:
    frozen_clock.advance(86_400)
    up_lo, up_hi, status = regs(cp.handle(req(0x04, 5, 3)))
    assert up_lo | up_hi << 16 == 100
    assert status & 0x02


def test_coolpro_ranges_and_exceptions(cp: CoolProDevice) -> None:
    assert answer(cp.handle(req(0x04, 0, 8)))[0] == 0x04
    assert answer(cp.handle(req(0x04, 7, 1)))[0] == 0x04
    assert answer(cp.handle(req(0x04, 100, 8)))[0] == 0x04
    for a, n in ((8, 1), (99, 1), (99, 2), (5, 4), (107, 2), (108, 1), (0, 9), (100, 9)):
        assert cp.handle(req(0x04, a, n)) == b"\x84\x02", (a, n)
    for a, n in ((3, 1), (2, 2), (0, 4)):
        assert cp.handle(req(0x03, a, n)) == b"\x83\x02", (a, n)
    # quantity outside 1..125: the standard's 03, checked before the address
    assert cp.handle(req(0x04, 0, 0)) == b"\x84\x03"
    assert cp.handle(req(0x03, 0, 126)) == b"\x83\x03"
    for fc in (0x01, 0x02, 0x05, 0x10, 0x17, 0x2B):
        assert cp.handle(bytes((fc,)) + b"\x00\x00\x00\x01") == bytes((fc | 0x80, 1))
    assert cp.handle(req(0x06, 3, 1)) == b"\x86\x02"
    assert cp.handle(req(0x06, 0, 0)) == b"\x86\x03"
    assert cp.handle(req(0x06, 0, 248)) == b"\x86\x03"
    assert cp.handle(req(0x06, 1, 5)) == b"\x86\x03"
    assert cp.handle(req(0x06, 2, 0x1234)) == b"\x86\x03"


def test_coolpro_writes_take_effect_at_reset(cp: CoolProDevice, frozen_clock: SimClock) -> None:
    assert cp.handle(req(0x06, 0, 42)) == req(0x06, 0, 42)  # echo
    assert cp.handle(req(0x06, 1, 1)) == req(0x06, 1, 1)
    assert regs(cp.handle(req(0x03, 0, 3))) == [42, 1, 0]
    assert (cp.address, cp.baud) == (40, 9600)  # still the old ones
    assert cp.handle(req(0x06, 2, 0xAA55)) == req(0x06, 2, 0xAA55)
    assert (cp.address, cp.baud) == (42, 19200)
    assert regs(cp.handle(req(0x03, 2, 1))) == [0]  # the reset register reads 0
    up_lo, up_hi, status = regs(cp.handle(req(0x04, 5, 3)))
    assert (up_lo, up_hi) == (0, 0)
    assert status & 0x01  # startup
    frozen_clock.advance(2.5)
    up_lo, up_hi, status = regs(cp.handle(req(0x04, 5, 3)))
    assert up_lo == 2
    assert not status & 0x01


def test_coolpro_broadcast_write_is_carried_out(cp: CoolProDevice) -> None:
    cp.handle_broadcast(req(0x06, 0, 77))
    assert cp.pending_address == 77
    cp.handle_broadcast(req(0x04, 0, 1))  # reads: nothing to do


def test_coolpro_status_bits_and_sensor_zeroes(cp: CoolProDevice, frozen_clock: SimClock) -> None:
    cp.set_status(0x8000 | 0x0004)  # a reserved bit and the input measurement fault
    vin, iin, vout, _iout, _temp, _, _, status = regs(cp.handle(req(0x04, 0, 8)))
    assert status == 0x8004
    assert (vin, iin) == (0, 0)
    assert vout > 0
    cp.clear_status(0x0004)
    assert regs(cp.handle(req(0x04, 7, 1))) == [0x8000]
    cp.set_status(0x40, seconds=3)
    assert regs(cp.handle(req(0x04, 4, 1))) == [0]
    frozen_clock.advance(3)
    assert regs(cp.handle(req(0x04, 7, 1))) == [0x8000]


def test_coolpro_pins_and_identity(cp: CoolProDevice) -> None:
    cp.pin("input_voltage_v", 24_500)
    cp.pin("uptime_s", 70_000)
    assert regs(cp.handle(req(0x04, 0, 1))) == [0x5FB4]  # the document's worked value
    assert regs(cp.handle(req(0x04, 5, 2))) == [4464, 1]
    cp.unpin()
    cp.set_identity(serial_number=0x12345678, hardware_revision=3)
    assert regs(cp.handle(req(0x04, 100, 3))) == [0x5678, 0x1234, 3]
    with pytest.raises(InvalidArgument):
        cp.pin("address", 1)


def test_coolpro_model_raises_and_clears_status_faults(frozen_clock: SimClock) -> None:
    cp = CoolProDevice(clock=frozen_clock, uptime=10.0)
    seen = set()
    for _ in range(24 * 360):  # 24 h in 10 s steps
        frozen_clock.advance(10)
        seen.add(cp.status() & 0x7C)
    assert 0 in seen
    assert len(seen) >= 3  # raised, and cleared again


def test_coolpro_is_deterministic_from_seed() -> None:
    def sample(seed: int) -> list[list[int]]:
        c = SimClock(0.0)
        c.freeze()
        d = CoolProDevice(seed=seed, clock=c)
        out = []
        for _ in range(20):
            c.advance(3.1)
            out.append(regs(d.handle(req(0x04, 0, 8))))
        return out

    assert sample(1) == sample(1)
    assert sample(1) != sample(2)


# -- hub -----------------------------------------------------------------------------


def test_hub_function_codes(hub: HubDevice) -> None:
    assert answer(hub.handle(req(0x03, 31, 10)))[0] == 0x03
    assert hub.handle(bytes.fromhex("10001f0001020000")) == b"\x90\x01"
    for fc in (0x04, 0x06, 0x01, 0x2B):
        assert hub.handle(req(fc, 31, 1)) == bytes((fc | 0x80, 1))


def test_hub_address_ranges(hub: HubDevice) -> None:
    assert len(regs(hub.handle(req(0x03, 31, 125)))) == 125
    assert len(regs(hub.handle(req(0x03, 606, 125)))) == 125  # ends at 730
    for a, n in ((30, 1), (0, 10), (731, 1), (700, 32), (606, 126), (31, 0), (1, 125)):
        assert hub.handle(req(0x03, a, n)) == b"\x83\x02", (a, n)


def test_hub_frame_is_at_most_255_bytes(hub: HubDevice) -> None:
    assert len(answer(hub.handle(req(0x03, 31, 125)))) + 3 == 255


@pytest.mark.parametrize(("firmware", "ok", "missing"), [
    ("1.07", [(31, 50), (131, 50)], [(31, 51), (81, 1), (131, 51), (231, 1), (431, 1)]),
    ("1.05", [(31, 50)], [(80, 2)]),
    ("2.18", [(31, 125), (331, 100)], [(431, 1), (531, 1), (631, 1), (400, 32)]),
    ("2.19", [(431, 100), (531, 100)], [(631, 1), (600, 32)]),
    ("2.22", [(531, 100)], [(631, 1)]),
    ("2.23", [(631, 100), (606, 125)], []),
    ("3.1", [(631, 100)], []),
])
def test_hub_firmware_profiles(frozen_clock: SimClock, firmware: str, ok: list[tuple[int, int]],
                               missing: list[tuple[int, int]]) -> None:
    hub = HubDevice(clock=frozen_clock, firmware=firmware)
    for a, n in ok:
        assert answer(hub.handle(req(0x03, a, n)))[0] == 0x03, (firmware, a, n)
    for a, n in missing:
        assert hub.handle(req(0x03, a, n)) == b"\x83\x02", (firmware, a, n)


def test_hub_firmware_switch_at_run_time(hub: HubDevice) -> None:
    hub.firmware = "1.07"
    assert hub.channels == 50
    assert not hub.supports("pressure_kpa")
    assert hub.handle(req(0x03, 331, 1)) == b"\x83\x02"
    hub.firmware = "2.23"
    assert answer(hub.handle(req(0x03, 331, 1)))[0] == 0x03


def test_hub_markers_and_units(hub: HubDevice) -> None:
    hub.configure(1, present=True, temperature=True, humidity=True, pressure=False,
                  temperature2=False, humidity_tenths=True)
    hub.configure(2, humidity=False, humidity_tenths=True)
    hub.configure(3, humidity=False, humidity_tenths=False)
    hub.configure(4, present=False)
    hub.set_humidity_unit(5, 1)
    hub.configure(5, humidity=True)
    hub.set_offline(1, False)
    assert hub.raw("humidity_pct", 2) == 0x8000  # no humidity, 0.1 % unit
    assert hub.raw("humidity_pct", 3) == 0x00FF  # no humidity, 1 % unit
    assert all(v == 0xFFFF for v in regs(hub.handle(req(0x03, 34, 1))))
    assert hub.raw("humidity_pct", 4) == 0xFFFF  # offline
    assert hub.raw("pressure_kpa", 1) == 0xFFFF  # no pressure sensor
    assert 0 <= hub.raw("humidity_pct", 1) <= 1000  # 0.1 %
    assert 0 <= hub.raw("humidity_pct", 5) <= 100  # 1 %
    assert hub.humidity_tenths[4] == 0
    assert hub.humidity_tenths[0] == 1
    assert Channel() == hub.channel(1)


def test_hub_offline_channel_reads_ffff_everywhere(hub: HubDevice) -> None:
    hub.configure(7, pressure=True, temperature2=True)
    hub.set_offline(7)
    for block in ("temperature_c", "humidity_pct", "pressure_temperature_c", "pressure_kpa",
                  "voltage_mv", "rssi_dbm", "temperature2_c"):
        assert hub.raw(block, 7) == 0xFFFF
    hub.set_offline(7, None)
    assert hub.raw("temperature_c", 7) != 0xFFFF


def test_hub_timed_offline_comes_back(hub: HubDevice, frozen_clock: SimClock) -> None:
    hub.configure(9, present=True)
    assert hub.raw("voltage_mv", 9) != 0xFFFF
    hub.set_offline(9, True, seconds=5)
    assert hub.raw("voltage_mv", 9) == 0xFFFF
    frozen_clock.advance(4.9)
    assert hub.raw("voltage_mv", 9) == 0xFFFF
    frozen_clock.advance(0.1)
    assert hub.raw("voltage_mv", 9) != 0xFFFF


def test_hub_values_encode_as_documented(frozen_clock: SimClock) -> None:
    hub = HubDevice(clock=frozen_clock, seed=3)
    negatives = 0
    for ch in range(1, 101):
        c = hub.channel(ch)
        t = hub.raw("temperature_c", ch)
        if c.present and c.temperature and t != 0xFFFF:
            negatives += bool(t & 0x8000)
            assert t & 0x7FFF < 1000  # tenths: under 100 °C
        r = hub.raw("rssi_dbm", ch)
        if r != 0xFFFF:
            assert -100 <= r - 0x10000 <= -40  # signed dBm
        v = hub.raw("voltage_mv", ch)
        if v != 0xFFFF:
            assert 2_900 <= v <= 3_700
    assert negatives > 0  # some channels sit in a freezer
    assert sign_magnitude(-125) == 0x807D
    assert sign_magnitude(125) == 125
    assert sign_magnitude(-40_000) != 0xFFFF


def test_hub_pins(hub: HubDevice) -> None:
    hub.pin("temperature_c", 1, 0x80FF)
    hub.pin("rssi_dbm", 100, -71 & 0xFFFF)
    assert regs(hub.handle(req(0x03, 31, 1))) == [0x80FF]
    assert regs(hub.handle(req(0x03, 630, 1))) == [0xFFB9]
    hub.unpin()
    assert regs(hub.handle(req(0x03, 31, 1))) != [0x80FF]


def test_hub_values_move_and_channels_go_offline_and_back(frozen_clock: SimClock) -> None:
    hub = HubDevice(clock=frozen_clock, seed=5)
    before = hub.registers()
    frozen_clock.advance(60)
    assert hub.registers() != before  # temperatures drift
    offline_seen: set[int] = set()
    back: set[int] = set()
    was = {ch: hub.raw("voltage_mv", ch) == 0xFFFF for ch in range(1, 101)}
    for _ in range(6 * 60):  # 6 h in 60 s steps
        frozen_clock.advance(60)
        for ch in range(1, 101):
            now = hub.raw("voltage_mv", ch) == 0xFFFF
            if now and not was[ch]:
                offline_seen.add(ch)
            if was[ch] and not now:
                back.add(ch)
            was[ch] = now
    assert offline_seen
    assert back


def test_hub_refresh_is_exact_whatever_the_request_pattern() -> None:
    """Values are a function of (seed, time): polling often or rarely sees the same."""
    c1, c2 = SimClock(0.0), SimClock(0.0)
    c1.freeze()
    c2.freeze()
    often, rarely = HubDevice(seed=9, clock=c1), HubDevice(seed=9, clock=c2)
    for _ in range(100):
        c1.advance(0.37)
        often.registers()
    c2.advance(37.0)
    assert often.registers() == rarely.registers()


def test_hub_addresses_1_to_255() -> None:
    HubDevice(255)
    with pytest.raises(InvalidArgument):
        HubDevice(0)
    with pytest.raises(InvalidArgument):
        HubDevice(256)


# -- specs ---------------------------------------------------------------------------


def test_make_device_specs() -> None:
    d = make_device("hub:250,firmware=1.07,delay=0.01-0.02,humidity=1")
    assert isinstance(d, HubDevice)
    assert d.address == 250
    assert d.channels == 50
    assert d.humidity_tenths == bytes(100)
    assert 0.01 <= d.turnaround() <= 0.02
    c = make_device("coolpro:41,gap=0,firmware=2.3.4,serial=0x10", baud=19200)
    assert isinstance(c, CoolProDevice)
    assert (c.address, c.baud, c.gap) == (41, 19200, 0.0)
    assert c.register("serial_number") == 16
    assert c.register("firmware_minor") == 3
    for bad in ("toaster", "hub:x", "hub,color=red", "coolpro:248", "coolpro,baud=1200"):
        with pytest.raises(InvalidArgument):
            make_device(bad)
    # the keys every device takes, the map's options, and the CoolPro's and hub's own
    assert make_device("coolpro,delay=0.02").gap == 0.02  # type: ignore[attr-defined]
    assert make_device("hub,humidity_unit=1").humidity_tenths == bytes(100)  # type: ignore[attr-defined]
    assert make_device("eastron-sdm630:3,firmware=1.2").firmware == "1.2"  # type: ignore[attr-defined]
    with pytest.raises(InvalidArgument, match=re.escape(
            "hub takes firmware=..., delay=..., baud=..., dynamic=..., humidity=..., "
            "humidity_unit=...")):
        make_device("hub,colour=red")


@pytest.mark.parametrize(("make", "name"), [
    (lambda: make_device("coolpro,gap=-1"), "bad value for gap: '-1'"),
    (lambda: make_device("coolpro,delay=-1"), "bad value for delay: '-1'"),
    (lambda: make_device("hub,delay=0.5-0.1"), "bad value for delay: '0.5-0.1'"),
    (lambda: CoolProDevice(gap=61), "coolpro: gap must be 0..60 s"),
    (lambda: HubDevice(response_delay=-1), "hub: response_delay must be 0..60 s"),
])
def test_a_wait_out_of_range_names_the_key_given(make: Callable[[], object], name: str) -> None:
    """A wait before the reply outside 0..60 s is refused naming the key or
    argument the user wrote (``gap``, not the engine's ``delay``)."""
    with pytest.raises(InvalidArgument, match=re.escape(name)):
        make()


def test_fault_specs_and_plan() -> None:
    f, p, a = parse_fault("late:0.25,delay=1.5,address=40")
    assert (f.kind, f.delay, p, a) == ("late", 1.5, 0.25, 40)
    f, p, a = parse_fault("sensor,channels=3+4,seconds=2")
    assert f.channels == (3, 4)
    assert p == 1.0
    for bad in ("nope", "late:2", "late:x", "late,delay", "busy,code=3", "late,colour=1"):
        with pytest.raises(InvalidArgument):
            parse_fault(bad)
    faults = Faults(seed=1)
    faults.inject("bad_crc", count=2, address=40)
    assert faults.pick(41, 3) is None
    assert faults.pick(40, 3).kind == "bad_crc"  # type: ignore[union-attr]
    assert faults.pick(40, 3, tcp=True) is None  # no CRC on TCP
    assert faults.pick(40, 3).kind == "bad_crc"  # type: ignore[union-attr]
    assert faults.pick(40, 3) is None
    assert faults.counts["bad_crc"] == 2
    faults.set_rate("no_reply", 0.5)
    hits = sum(faults.pick(1, 3) is not None for _ in range(1000))
    assert 400 < hits < 600
    again = Faults(seed=1)
    again.set_rate("no_reply", 0.5)
    first = [again.pick(1, 3) is not None for _ in range(50)]
    again2 = Faults(seed=1)
    again2.set_rate("no_reply", 0.5)
    assert first == [again2.pick(1, 3) is not None for _ in range(50)]
