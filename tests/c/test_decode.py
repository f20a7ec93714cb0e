"""The decoders (the hub's and the CoolPro's maps through the C map decoder)
against the pure-Python reference (tests/reference.py): every 16-bit value
of each encoding, random blocks, and the documents' worked values."""

from __future__ import annotations

import math
from array import array
from datetime import UTC, datetime

import pytest
import reference as ref
from hypothesis import given, settings
from hypothesis import strategies as st

from pymb.devices import COOLPRO, CoolProStatus, State, decode_hub
from pymb.devices.coolpro import CoolProTelemetry, decode_identity, decode_telemetry
from pymb.devices.hubreading import BLOCKS, CHANNELS, HUB_REGISTERS, block_index

STATE = {ref.VALUE: State.VALUE, ref.OFFLINE: State.OFFLINE, ref.NO_SENSOR: State.NO_SENSOR}


def same(a: float, b: float) -> bool:
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) and math.isnan(b)
    return a == b and math.copysign(1, a) == math.copysign(1, b)


def check_reading(regs: list[int], units: list[float], channels: int) -> None:
    r = decode_hub(array("H", regs), units, channels=channels)
    for index, block in enumerate(BLOCKS):
        values = getattr(r, block.name)
        states = r.states(block.name)
        assert len(values) == channels
        for c in range(channels):
            raw = regs[index * CHANNELS + c]
            want_state, want = ref.hub_value(index, raw, units[c])
            assert same(values[c], want), (block.name, c, hex(raw), values[c], want)
            assert states[c] == STATE[want_state]


ENCODINGS = [  # (block that uses the encoding, humidity unit)
    ("temperature_c", 0.1),  # sign-magnitude tenths (also blocks 2 and 6)
    ("humidity_pct", 1),
    ("humidity_pct", 0.1),
    ("pressure_kpa", 0.1),  # unsigned (also voltage)
    ("rssi_dbm", 0.1),  # two's complement
]


@pytest.mark.parametrize(("name", "unit"), ENCODINGS)
def test_every_16_bit_value_of_each_encoding(name: str, unit: float) -> None:
    index = block_index(name)
    regs = array("H", bytes(2 * HUB_REGISTERS))
    base = index * CHANNELS
    for start in range(0, 0x10000, CHANNELS):
        raws = range(start, min(start + CHANNELS, 0x10000))
        regs[base:base + len(raws)] = array("H", raws)
        r = decode_hub(regs, unit)
        values, states = getattr(r, name), r.states(name)
        for c, raw in enumerate(raws):
            want_state, want = ref.hub_value(index, raw, unit)
            got = values[c]
            ok = got == want and (got != 0 or math.copysign(1, got) == math.copysign(1, want))
            if not ok and not (got != got and want != want):
                pytest.fail(f"{name} raw {raw:#06x} unit {unit}: {got!r} != {want!r}")
            assert states[c] == STATE[want_state]


@settings(max_examples=100, deadline=None)
@given(
    data=st.binary(min_size=2 * 700, max_size=2 * 700),
    markers=st.lists(
        st.tuples(st.integers(0, 699), st.sampled_from([0xFFFF, 0x8000, 0x00FF, 0x7FFF, 0])),
        max_size=60,
    ),
    units=st.lists(st.sampled_from([1, 0.1]), min_size=100, max_size=100),
    channels=st.integers(1, 100),
)
def test_random_blocks_match_reference(data: bytes, markers: list[tuple[int, int]],
                                       units: list[float], channels: int) -> None:
    regs = list(array("H", data))
    for i, m in markers:
        regs[i] = m
    check_reading(regs, units[:channels], channels)


def test_documented_markers() -> None:
    regs = [0] * 700
    regs[0] = 0xFFFF  # channel 1 temperature offline
    regs[1] = 0x8000  # channel 2 temperature -0.0, not a marker
    regs[2] = 0x8000 | 125  # channel 3: -12.5 degC
    regs[100] = 0x00FF  # channel 1 humidity, 1 % unit: no humidity
    regs[101] = 0x8000  # channel 2 humidity, 0.1 % unit: no humidity
    regs[102] = 0x00FF  # channel 3 humidity, 0.1 % unit: 25.5 %
    regs[500] = 0xFFB5  # channel 1 RSSI: -75 dBm
    regs[501] = 0xFFFF  # channel 2 RSSI offline
    units = [1, 0.1, 0.1] + [0.1] * 97
    r = decode_hub(regs, units)
    assert r.state("temperature_c", 1) is State.OFFLINE
    assert math.isnan(r.temperature_c[0])
    assert same(r.temperature_c[1], -0.0)
    assert r.state("temperature_c", 2) is State.VALUE
    assert r.temperature_c[2] == -12.5
    assert r.state("humidity_pct", 1) is State.NO_SENSOR
    assert r.state("humidity_pct", 2) is State.NO_SENSOR
    assert r.humidity_pct[2] == 25.5
    assert r.rssi_dbm[0] == -75.0
    assert r.state("rssi_dbm", 2) is State.OFFLINE
    ch = r.channel(3)
    assert ch.channel == 3
    assert ch.temperature_c == -12.5
    assert ch.humidity_pct == 25.5
    assert ch.states["temperature_c"] is State.VALUE


def test_unsupported_blocks_and_channel_views() -> None:
    r = decode_hub(range(700), 1, channels=50, unsupported=["voltage_mv", "temperature2_c"])
    assert len(r.voltage_mv) == 50
    assert all(math.isnan(v) for v in r.voltage_mv)
    assert set(r.states("voltage_mv")) == {State.UNSUPPORTED}
    assert r.unsupported == {"voltage_mv", "temperature2_c"}
    assert r.pressure_kpa[49] == 349.0
    with pytest.raises(ValueError, match=r"channel must be 1\.\.50, got 51"):
        r.channel(51)
    with pytest.raises(ValueError, match=r"channel must be 1\.\.50, got 0"):
        r.channel(0)
    d = r.as_dict()
    assert d["voltage_mv"][0] is None
    assert d["pressure_kpa"][0] == 300.0


def test_bad_decode_arguments() -> None:
    with pytest.raises(ValueError, match="700 registers"):
        decode_hub([0] * 699)
    with pytest.raises(ValueError, match="channels"):
        decode_hub([0] * 700, channels=101)
    with pytest.raises(ValueError, match="humidity unit"):
        decode_hub([0] * 700, 0.5)
    with pytest.raises(ValueError, match="humidity units"):
        decode_hub([0] * 700, [1, 0.1])


def test_a_decoding_made_ready_once_refuses_what_it_refused_and_decodes_the_same() -> None:
    """decode_hub keeps its decoding by (channels, one unit): a channel count
    that is not an int is refused however often a valid one was decoded,
    and a later decode gives what the first gave (per-channel units too)."""
    regs = array("H", range(700))
    first = decode_hub(regs, 1, channels=50)
    mixed = decode_hub(regs, [1.0] * 25 + [0.1] * 25, channels=50)
    for bad in (50.0, True):
        with pytest.raises(ValueError, match="channels"):
            decode_hub(regs, 1, channels=bad)  # type: ignore[arg-type]
    again = decode_hub(regs, 1.0, channels=50)
    assert again.channels == 50
    assert again.registers is regs
    assert list(again.values) == list(first.values)
    assert list(again.raw_states) == list(first.raw_states)
    assert again.values is not first.values  # (each reading its own arrays)
    twice = decode_hub(regs, [1.0] * 25 + [0.1] * 25, channels=50)
    assert list(twice.values) == list(mixed.values)
    assert list(mixed.humidity_pct) != list(first.humidity_pct)


def test_views_convert_to_numpy_without_copy() -> None:
    np = pytest.importorskip("numpy")
    r = decode_hub(range(700))
    a = np.asarray(r.temperature_c)
    assert a.dtype == np.float64
    assert a.shape == (100,)
    r.values[0] = 42.0
    assert a[0] == 42.0  # a view, not a copy


# -- CoolPro ------------------------------------------------------------------


def test_coolpro_worked_values() -> None:
    # [CP] ch. 02 / 04 / 06: 24.5 V, 3.25 A, 24.0 V, 3.20 A, 25.8 degC, uptime 70000 s.
    regs = array("H", [0x5FB4, 0x0CB2, 0x5DC0, 0x0C80, 0x64C8, 4464, 1, 0x8041])
    t = decode_telemetry(regs)
    assert (t.input_voltage_v, t.input_current_a, t.output_voltage_v, t.output_current_a,
            t.temperature_c) == (24.5, 3.25, 24.0, 3.2, 25.8)
    assert t.uptime_s == 70000 == ref.u32_low_word_first(4464, 1)
    flags = t.status
    assert CoolProStatus.SYSTEM_STARTUP in flags
    assert CoolProStatus.TEMPERATURE_SENSOR_FAULT in flags
    assert flags.reserved == 0x8000
    assert int(flags) == 0x8041  # reserved bit kept
    d = decode_identity(array("H", [0x3039, 0, 2, 1, 0, 0, 0x5E00, 0x6A50]))
    assert d.serial_number == 12345
    assert (d.hardware_revision, d.firmware_version) == (2, "1.0.0")
    assert d.manufactured.year == 2026
    assert d.manufactured == datetime.fromtimestamp(
        ref.u32_low_word_first(0x5E00, 0x6A50), UTC)


@given(st.lists(st.integers(0, 0xFFFF), min_size=8, max_size=8))
def test_coolpro_telemetry_matches_reference(raw: list[int]) -> None:
    t = decode_telemetry(array("H", raw))
    got = (t.input_voltage_v, t.input_current_a, t.output_voltage_v, t.output_current_a,
           t.temperature_c, t.uptime_s, int(t.status))
    assert got == ref.coolpro_telemetry(raw)


# -- the maps and the facades agree ----------------------------------------------


def test_coolpro_record_agrees_with_the_map() -> None:
    assert [(r.function, r.address, r.count) for r in COOLPRO.plan("telemetry")] == [(4, 0, 8)]
    assert [(r.function, r.address, r.count) for r in COOLPRO.plan("identity")] == [(4, 100, 8)]
    # The telemetry record's fields, in order, are the map's telemetry points.
    fields = [f for f in CoolProTelemetry.__dataclass_fields__ if f != "registers"]
    assert fields == [p.name for p in COOLPRO.points.values() if p.group == "telemetry"]
    # CoolProStatus names the map's status bits.
    assert {m.name: m.value for m in CoolProStatus} == {
        name: 1 << bit for bit, name in COOLPRO.points["status"].flags.items()
    }
