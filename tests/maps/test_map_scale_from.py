"""``scale_from`` (a value scaled by 10^SF, SF another point read in the same
poll), ``mask`` (the bits of a value under a mask) and markers with don't-care
bits: the C decoder against the Python reference codec, on random points and
registers, and the loader's refusals."""

from __future__ import annotations

import math
import struct
from array import array
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from pymb import InvalidArgument, maps
from pymb.maps import Decoder

HEAD = 'schema = "pymb.map/1"\n[device]\nid = "t"\ntable = "holding"\n'
WIDTH = {"u16": 1, "i16": 1, "u32": 2, "i32": 2, "u64": 4, "i64": 4, "f32": 2, "sm16": 1,
         "u8_lo": 1, "i8_hi": 1}


def same(a: Any, b: Any) -> bool:
    """Equal, and of the same type: ints stay ints, -0.0 is not 0.0, None is None."""
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b, strict=True))
    if type(a) is not type(b):
        return False
    if isinstance(a, float):
        return a == b and math.copysign(1, a) == math.copysign(1, b)
    return bool(a == b)


def both(m: maps.Map, regs: list[int], name: str, sf: int | None) -> tuple[Any, Any]:
    """The C decoder's (value, state) of ``name`` over ``regs`` (the whole
    table from 0), checked against the reference given the scale factor."""
    d = Decoder(m, [name], address=0)
    got = d.read(array("H", regs + [0] * (d.count - len(regs))))[name]
    state = d.states()[name]
    p = m.points[name]
    py, py_state = m.decode_state(name, regs[p.address:p.address + p.span], scale_factor=sf)
    assert same(got, py), (got, py)
    assert state == py_state, (state, py_state)
    return got, state


@st.composite
def scaled_points(draw: st.DrawFn) -> tuple[str, list[int], int | None]:
    typ = draw(st.sampled_from(sorted(WIDTH)))
    n = WIDTH[typ]
    block = draw(st.booleans())
    order = draw(st.sampled_from(["ABCD", "CDAB", "BADC", "DCBA"]))
    sf_order = draw(st.sampled_from(["AB", "BA"]))
    sf_type = draw(st.sampled_from(["sunssf", "i16"]))
    channels = draw(st.integers(1, 4)) if block else 1
    sf_at = n * channels  # the scale factor right after the value(s)
    head = (f'[[block]]\nname = "v"\nfirst = 0\ncount = {channels}\n' if block
            else '[[point]]\nname = "v"\naddress = 0\n')
    text = (HEAD + head + f'type = "{typ}"\norder = "{order}"\nscale_from = "v_sf"\n'
            + (f"offset = {draw(st.sampled_from([-40.0, 0.5]))!r}\n" if draw(st.booleans())
               else "")
            + f'[[point]]\nname = "v_sf"\naddress = {sf_at}\ntype = "{sf_type}"\n'
            f'order = "{sf_order}"\n')
    regs = draw(st.lists(st.integers(0, 0xFFFF), min_size=sf_at, max_size=sf_at))
    sf = draw(st.one_of(st.integers(-12, 12), st.sampled_from([-32768, 32767, -11, 11])))
    word = sf & 0xFFFF
    regs.append(((word & 0xFF) << 8 | word >> 8) if sf_order == "BA" else word)
    return text, regs, sf


@given(scaled_points())
def test_c_decoder_matches_the_reference_with_a_scale_factor(
        case: tuple[str, list[int], int | None]) -> None:
    text, regs, sf = case
    m = maps.loads(text)
    ref_sf = m.decode("v_sf", regs[-1:])
    assert ref_sf == (None if sf == -32768 and m.points["v_sf"].type == "sunssf" else sf)
    _value, state = both(m, regs, "v", sf)
    ok = sf is not None and -10 <= sf <= 10
    states = state if isinstance(state, list) else [state]
    assert all(s in ("value", "nan", "no_scale") for s in states)
    if not ok:
        assert all(s == "no_scale" for s in states), (sf, state)


def test_a_sunspec_power_is_never_ten_times_wrong() -> None:
    m = maps.loads(HEAD + '''
[[point]]
name = "W"
address = 40083
type = "i16"
scale_from = "W_SF"
unit = "W"
[[point]]
name = "W_SF"
address = 40084
type = "sunssf"
''')
    d = Decoder(m, ["W"])
    assert d.names == ("W", "W_SF")  # the scale factor comes with the value
    assert d.read([3342, 1]) == {"W": 33420.0, "W_SF": 1}
    assert d.read([3342, 0]) == {"W": 3342.0, "W_SF": 0}
    assert d.read([-1896 & 0xFFFF, -1 & 0xFFFF])["W"] == -189.6  # divides: the nearest double
    assert d.read([3342, 0x8000]) == {"W": None, "W_SF": None}
    assert d.states() == {"W": "no_scale", "W_SF": "not_implemented"}
    assert d.read([3342, 11])["W"] is None
    assert d.states()["W"] == "no_scale"
    assert m.decode("W", [3342]) is None  # no scale factor given: no value, never a guess
    assert m.plan().spans == ((40083, 2),)


def test_masked_values_and_markers_with_dont_care_bits() -> None:
    m = maps.loads(HEAD + '''
[[point]]
name = "state"
address = 0
type = "u16"
mask = 0x006F
values = { 0x23 = "switched_on", 0x27 = "operation_enabled" }
access = "rw"
[[point]]
name = "energy"
address = 1
type = "i32"
order = "CDAB"
markers = { "0x7FFFxxxx" = "overflow", "0b1xxx_xxxx_xxxx_xxxx_xxxx_xxxx_xxxx_xxx1" = "odd" }
''')
    for regs, want, states in [
        ([0xFFA3, 0x1234, 0x0001], {"state": 0x23, "energy": 0x00011234}, "value"),
        ([0x0027, 0x0000, 0x7FFF], {"state": 0x27, "energy": None}, "overflow"),
        ([0x0027, 0xFFFF, 0x7FFF], {"state": 0x27, "energy": None}, "overflow"),
        ([0x0027, 0x0001, 0x8000], {"state": 0x27, "energy": None}, "odd"),
        ([0x0027, 0x0002, 0x8000], {"state": 0x27, "energy": -0x7FFFFFFE}, "value"),
    ]:
        d = Decoder(m)
        assert d.read(regs) == want
        assert d.states()["energy"] == states
        for name in want:
            p = m.points[name]
            assert same(m.decode(name, regs[p.address:p.address + p.count]), want[name])
    # a masked write keeps the bits outside the mask
    assert m.encode("state", "operation_enabled", current=[0xFF80]) == [0xFF80 | 0x27]
    with pytest.raises(InvalidArgument, match="mask"):
        m.encode("state", "operation_enabled")


@given(raw=st.integers(0, 0xFFFFFFFF), mask=st.integers(1, 0xFFFFFFFF),
       pattern=st.integers(0, 0xFFFF), order=st.sampled_from(["ABCD", "CDAB", "BADC"]))
def test_masks_and_patterns_match_the_reference(raw: int, mask: int, pattern: int,
                                                order: str) -> None:
    m = maps.loads(HEAD + f'''
[[point]]
name = "p"
address = 0
type = "u32"
order = "{order}"
mask = {mask:#x}
markers = {{ "0x{pattern:04X}xxxx" = "high", 0x{(raw ^ 0x10) & mask:X} = "exact" }}
''')
    regs = [raw >> 16, raw & 0xFFFF]
    wire = {"ABCD": regs, "CDAB": regs[::-1],
            "BADC": [((w & 0xFF) << 8) | (w >> 8) for w in regs]}[order]
    value, state = both(m, wire, "p", None)
    exact = (raw ^ 0x10) & mask == raw & mask
    high = (raw & mask) >> 16 == pattern
    assert state == ("exact" if exact else "high" if high else "value")
    assert value == (None if exact or high else raw & mask)


@pytest.mark.parametrize(("fields", "message"), [
    ('scale_from = "nope"', "scale_from names no point 'nope'"),
    ('scale_from = "other"', "scale_from 'other' is a u16; a scale factor is a sunssf or i16"),
    ('scale_from = "sf"\nscale = 0.1', "scale or scale_from, not both"),
    ('scale_from = "sf_in"', "is in the input table, the point in holding"),
    ('mask = 0x1FFFF', "mask must be a whole number 1..65535"),
    ('markers = { "0x7FFFFxxxx" = "big" }', "wider than the value's 16 bits"),
    ('markers = { "0x7Gxx" = "bad" }', "neither a whole number nor a pattern"),
])
def test_the_loader_refuses_with_one_line(fields: str, message: str) -> None:
    text = HEAD + f'''
[[point]]
name = "v"
address = 0
type = "u16"
{fields}
[[point]]
name = "other"
address = 1
type = "u16"
[[point]]
name = "sf"
address = 2
type = "sunssf"
[[point]]
name = "sf_in"
address = 2
table = "input"
type = "sunssf"
'''
    with pytest.raises(maps.MapError) as e:
        maps.loads(text, source="dev.toml")
    assert message in str(e.value)
    assert "\n" not in str(e.value)
    assert str(e.value).startswith("dev.toml: point 'v'")


def test_the_map_simulator_serves_scaled_values_with_their_scale_factor() -> None:
    from pymb.sim.mapsim import MapSimDevice

    m = maps.loads(HEAD + '''
[[point]]
name = "W"
address = 100
type = "i16"
scale_from = "W_SF"
example = 33420.0
[[point]]
name = "W_SF"
address = 101
type = "sunssf"
example = 1
[[point]]
name = "Hz"
address = 102
type = "u16"
scale_from = "Hz_SF"
[[point]]
name = "Hz_SF"
address = 103
type = "sunssf"
example = -2
[[point]]
name = "state"
address = 104
type = "u16"
mask = 0x006F
example = 0x27
''')
    sim = MapSimDevice(m, 1, dynamic=False)
    reply = sim.handle(bytes((3, 0, 100, 0, 5)))
    assert reply is not None
    regs = list(struct.unpack(">5H", reply[2:]))
    assert regs[:2] == [3342, 1]
    got = Decoder(m).read(regs)
    assert got["W"] == 33420.0
    assert got["state"] == 0x27
    hz = got["Hz"]
    assert isinstance(hz, float)
    assert hz == regs[2] / 100  # a modelled value, encoded with its scale factor
