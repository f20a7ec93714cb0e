"""The reference codec (pure Python): every type and order of pymb.map/1
section 3, scale and markers, and encode as decode's inverse."""

from __future__ import annotations

import math
import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pymb import InvalidArgument, maps

HEAD = 'schema = "pymb.map/1"\n[device]\nid = "t"\ntable = "holding"\n'


def point_map(fields: str) -> maps.Map:
    return maps.loads(HEAD + '[[point]]\nname = "p"\naddress = 0\naccess = "rw"\n' + fields)


def dec(fields: str, regs: list[int]) -> object:
    return point_map(fields).decode("p", regs)


# 230.5 as a float32 is 0x43668000; each order's registers as they arrive.
@pytest.mark.parametrize(("order", "regs"), [
    ("ABCD", [0x4366, 0x8000]), ("CDAB", [0x8000, 0x4366]),
    ("BADC", [0x6643, 0x0080]), ("DCBA", [0x0080, 0x6643]),
    ("ABDC", [0x4366, 0x0080]),
])
def test_f32_orders(order: str, regs: list[int]) -> None:
    assert dec(f'type = "f32"\norder = "{order}"\n', regs) == 230.5


def test_64_bit_orders_generalise() -> None:
    value = 0x0102030405060708
    assert dec('type = "u64"\n', [0x0102, 0x0304, 0x0506, 0x0708]) == value
    assert dec('type = "u64"\norder = "CDAB"\n', [0x0708, 0x0506, 0x0304, 0x0102]) == value
    assert dec('type = "u64"\norder = "BADC"\n', [0x0201, 0x0403, 0x0605, 0x0807]) == value
    assert dec('type = "u64"\norder = "DCBA"\n', [0x0807, 0x0605, 0x0403, 0x0201]) == value
    assert dec('type = "u64"\norder = "GHEFCDAB"\n', [0x0708, 0x0506, 0x0304, 0x0102]) == value
    assert dec('type = "u32"\norder = "BCDA"\n', [0x0203, 0x0401]) == 0x01020304


def test_integers_stay_exact() -> None:
    assert dec('type = "u64"\n', [0xFFFF] * 4) == 2**64 - 1
    assert dec('type = "u64"\n', [0x0020, 0, 0, 1]) == 2**53 + 1
    assert dec('type = "i64"\n', [0xFFFF] * 4) == -1
    assert dec('type = "i64"\n', [0x8000, 0, 0, 0]) == -(2**63)
    assert dec('type = "i32"\n', [0xFFFF, 0xFFFE]) == -2
    assert dec('type = "i16"\n', [0x8000]) == -32768
    assert isinstance(dec('type = "u16"\n', [7]), int)
    assert dec('type = "u16"\norder = "BADC"\n', [0x3412]) == 0x1234


def test_scale_is_a_division_for_decimal_powers() -> None:
    assert dec('type = "i16"\nscale = 0.1\n', [(-1896) & 0xFFFF]) == -189.6
    assert dec('type = "sm16"\nscale = 0.1\n', [0x8000 | 1896]) == -189.6
    assert dec('type = "u16"\nscale = 0.001\n', [24500]) == 24.5
    assert dec('type = "u16"\nscale = 0.01\n', [4950]) == 49.5
    assert dec('type = "u16"\nscale = 0.001\n', [3250]) == 3250 / 1000
    assert dec('type = "u16"\nscale = 2\noffset = -40\n', [30]) == 20.0
    assert dec('type = "u16"\nscale = 0.5\n', [3]) == 1.5
    assert isinstance(dec('type = "u16"\nscale = 1\n', [3]), float)
    # a decimal power divides: never -189.60000000000002
    assert -1896 * 0.1 != -189.6


def test_sign_magnitude() -> None:
    assert dec('type = "sm16"\n', [0x8005]) == -5
    assert dec('type = "sm16"\n', [0x0005]) == 5
    v = dec('type = "sm16"\nscale = 0.1\n', [0x8000])
    assert v == 0.0
    assert math.copysign(1.0, v) == -1.0  # type: ignore[arg-type]


def test_halves_bits_and_bit_fields() -> None:
    assert dec('type = "u8_hi"\n', [0x12FE]) == 0x12
    assert dec('type = "u8_lo"\n', [0x12FE]) == 0xFE
    assert dec('type = "i8_lo"\n', [0x12FE]) == -2
    assert dec('type = "u8_hi"\norder = "BADC"\n', [0x12FE]) == 0xFE
    assert dec('type = "bit"\nbit = 15\n', [0x8000]) is True
    assert dec('type = "bit"\nbit = 0\n', [0x8000]) is False
    assert dec('type = "bits"\nshift = 4\nwidth = 4\n', [0x00A5]) == 0xA
    assert dec('type = "bit"\ncount = 2\nbit = 16\norder = "CDAB"\n', [0, 1]) is True


def test_markers_and_nan_are_none_with_a_named_state() -> None:
    m = point_map('type = "u16"\nscale = 0.1\n'
                  'markers = { 0xFFFF = "offline", 0x8000 = "no_sensor" }\n')
    assert m.decode_state("p", [0xFFFF]) == (None, "offline")
    assert m.decode_state("p", [0x8000]) == (None, "no_sensor")
    assert m.decode_state("p", [5]) == (0.5, "value")
    m = point_map('type = "i16"\nmarkers = { -1 = "offline" }\n')
    assert m.decode_state("p", [0xFFFF]) == (None, "offline")
    m = point_map('type = "f32"\n')
    assert m.decode_state("p", [0x7FC0, 0]) == (None, "nan")
    assert m.decode("p", [0x7F80, 0]) == math.inf
    m = point_map('type = "f32"\nmarkers = { 0xFFFFFFFF = "offline" }\n')
    assert m.decode_state("p", [0xFFFF, 0xFFFF]) == (None, "offline")


def test_f16_and_f64() -> None:
    assert dec('type = "f16"\n', [0x3C00]) == 1.0
    assert dec('type = "f16"\n', [0xC000]) == -2.0
    regs = list(struct.unpack(">4H", struct.pack(">d", math.pi)))
    assert dec('type = "f64"\n', regs) == math.pi
    assert dec('type = "f64"\norder = "CDAB"\n', regs[::-1]) == math.pi


def test_strings_in_both_layouts_and_encodings() -> None:
    regs = [0x5344, 0x4D31, 0x3230, 0x0000]  # "SDM120"
    assert dec('type = "string"\ncount = 4\n', regs) == "SDM120"
    swapped = [(r >> 8) | (r & 0xFF) << 8 for r in regs]
    assert dec('type = "string"\ncount = 4\norder = "BADC"\n', swapped) == "SDM120"
    assert dec('type = "string"\ncount = 4\norder = "CDAB"\n', regs) == "SDM120"
    low = [ord(c) for c in "SDM1"]
    assert dec('type = "string"\ncount = 4\nstring_bytes = "low"\n', low) == "SDM1"
    assert dec('type = "string"\ncount = 4\nstring_bytes = "high"\n', [c << 8 for c in low]) \
        == "SDM1"
    m = point_map('type = "string"\ncount = 2\n')
    assert m.decode_state("p", [0x41FF, 0x4200]) == (None, "invalid_text")
    assert dec('type = "string"\ncount = 2\nencoding = "latin-1"\n', [0x41E9, 0]) == "Aé"
    assert dec('type = "string"\ncount = 2\nencoding = "utf-8"\n', [0xC3A9, 0x2100]) == "é!"
    assert dec('type = "raw"\ncount = 3\n', [1, 2, 0xFFFF]) == [1, 2, 0xFFFF]


def test_encode_checks_before_anything_is_sent() -> None:
    m = maps.loads(HEAD + """
[[point]]
name = "ro"
address = 0
type = "u16"
[[point]]
name = "hz"
address = 1
type = "u16"
scale = 0.01
access = "rw"
valid = [45.0, 65.0]
[[point]]
name = "mode"
address = 2
type = "u16"
access = "w"
values = { 0 = "stop", 1 = "run" }
[[point]]
name = "flag"
address = 2
type = "bit"
bit = 3
access = "rw"
[[point]]
name = "name"
address = 3
type = "string"
count = 2
access = "rw"
""")
    assert m.encode("hz", 49.5) == [4950]
    assert m.encode("mode", "run") == [1]
    assert m.encode("mode", 0) == [0]
    assert m.encode("name", "abc") == [0x6162, 0x6300]
    assert m.encode("flag", True, current=[0x0101]) == [0x0109]
    for name, value, why in [("ro", 1, "read-only"), ("hz", 70.0, "valid range"),
                             ("mode", "go", "not one of its values"), ("mode", 5, "values"),
                             ("flag", 1, "current"), ("name", "abcde", "longer"),
                             ("hz", "x", "number"), ("name", "a\0b", "NUL")]:
        with pytest.raises(InvalidArgument, match=why):
            m.encode(name, value)


def test_a_scaled_value_is_sent_at_the_nearest_step_and_never_outside_valid() -> None:
    m = point_map('type = "u16"\nscale = 0.01\nvalid = [45.0, 65.0]\n')
    assert m.encode("p", 49.555) == [4956]
    assert m.encode("p", 64.996) == [6500]
    coarse = point_map('type = "u16"\nscale = 2\nvalid = [2.5, 10]\n')
    assert coarse.encode("p", 10) == [5]
    assert coarse.encode("p", 3.2) == [2]   # 4: the nearest step, inside
    with pytest.raises(InvalidArgument) as info:   # 2 would be sent: below valid
        coarse.encode("p", 2.5)
    assert str(info.value) == ("point 'p': 2.5 would be written as 2 (the nearest step of its "
                               "scale), outside its valid range 2.5..10")


@settings(max_examples=300, deadline=None)
@given(layout=st.sampled_from(["both", "high", "low"]), order=st.sampled_from(["ABCD", "BADC"]),
       encoding=st.sampled_from(["ascii", "latin-1", "utf-8"]), text=st.text(max_size=8))
def test_a_text_encode_takes_reads_back_as_written(layout: str, order: str, encoding: str,
                                                    text: str) -> None:
    m = point_map(f'type = "string"\ncount = 4\nstring_bytes = "{layout}"\n'
                  f'order = "{order}"\nencoding = "{encoding}"\n')
    try:
        regs = m.encode("p", text)
    except InvalidArgument:
        return  # refused: too long, not in the encoding, or a NUL, which would end it
    assert m.decode("p", regs) == text


types_ = st.sampled_from(["u16", "i16", "u32", "i32", "u64", "i64", "sm16", "u8_hi", "i8_lo"])
orders = st.sampled_from(["ABCD", "CDAB", "BADC", "DCBA"])


@settings(max_examples=300, deadline=None)
@given(typ=types_, order=orders, data=st.data())
def test_encode_then_decode_is_the_identity(typ: str, order: str, data: st.DataObject) -> None:
    m = point_map(f'type = "{typ}"\norder = "{order}"\n')
    lo, hi = maps.TYPES[typ].raw_range()
    value = data.draw(st.integers(lo, hi))
    regs = m.encode("p", value, current=[0])
    assert all(0 <= r <= 0xFFFF for r in regs)
    assert m.decode("p", regs) == value


@settings(max_examples=200, deadline=None)
@given(order=orders, value=st.floats(width=32, allow_nan=False))
def test_f32_round_trip(order: str, value: float) -> None:
    m = point_map(f'type = "f32"\norder = "{order}"\n')
    assert m.decode("p", m.encode("p", value)) == value


def test_builtin_maps_decode_the_documents_worked_values() -> None:
    cp = maps.builtin("coolpro")
    # [CP]: 5F B4 0C B2 5D C0 0C 80 = Vin 24.5 V, Iin 3.25 A, Vout 24.0 V, Iout 3.20 A
    assert [cp.decode(n, [r]) for n, r in zip(
        ("input_voltage_v", "input_current_a", "output_voltage_v", "output_current_a"),
        (0x5FB4, 0x0CB2, 0x5DC0, 0x0C80), strict=True)] == [24.5, 3.25, 24.0, 3.2]
    assert cp.decode("uptime_s", [4464, 1]) == 70000
    assert cp.decode("serial_number", [0x3039, 0]) == 12345
    assert cp.flag_names("status", 0x8041) == ["SYSTEM_STARTUP", "TEMPERATURE_SENSOR_FAULT"]
    assert cp.encode("baud_rate_index", "38400") == [2]
    assert cp.encode("reset", 0xAA55) == [0xAA55]
    with pytest.raises(InvalidArgument):
        cp.encode("reset", 1)
