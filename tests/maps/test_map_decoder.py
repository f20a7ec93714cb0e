"""The C table decoder (pymb_map_decode through pymb.maps.Decoder) against
the Python reference codec, and both against peers that are not pymb:
Telegraf's inputs.modbus test table, libmodbus's own float getters, and
pymodbus's register conversions."""

from __future__ import annotations

import math
import random
import struct
from array import array
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pymb import InvalidArgument, maps
from pymb.maps import Decoder

HEAD = 'schema = "pymb.map/1"\n[device]\nid = "t"\ntable = "holding"\n'


def same(a: Any, b: Any) -> bool:
    """Equal, and of the same type: ints stay ints, -0.0 is not 0.0, None is None."""
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b, strict=True))
    if type(a) is not type(b):
        return False
    if isinstance(a, float):
        return a == b and math.copysign(1, a) == math.copysign(1, b)
    return bool(a == b)


def one(fields: str) -> maps.Map:
    return maps.loads(HEAD + '[[point]]\nname = "p"\naddress = 0\n' + fields)


def both(m: maps.Map, regs: list[int], name: str = "p") -> tuple[Any, Any]:
    d = Decoder(m, [name])
    c = d.read(array("H", regs))[name]
    c_state = d.states()[name]
    py, py_state = m.decode_state(name, regs)
    assert same(c, py), (c, py)
    assert c_state == py_state
    return c, c_state


# -- the C decoder against the Python reference, on random points and registers

WIDTH = {"u16": 1, "i16": 1, "u32": 2, "i32": 2, "u64": 4, "i64": 4, "f16": 1, "f32": 2,
         "f64": 4, "sm16": 1, "u8_hi": 1, "u8_lo": 1, "i8_hi": 1, "i8_lo": 1}
SCALES = [None, 0.1, 0.01, 0.001, 1e-6, 1.0, 2.5, 10.0, -0.5, 1 / 3]


@st.composite
def numeric_points(draw: st.DrawFn) -> tuple[str, list[int]]:
    typ = draw(st.sampled_from(sorted(WIDTH)))
    n = WIDTH[typ]
    letters = "ABCDEFGH"[:2 * n]
    order = draw(st.one_of(st.sampled_from(["ABCD", "CDAB", "BADC", "DCBA"]),
                           st.permutations(letters).map("".join)))
    fields = f'type = "{typ}"\norder = "{order}"\n'
    scale = draw(st.sampled_from(SCALES))
    if scale is not None:
        fields += f"scale = {scale!r}\n"
    if draw(st.booleans()):
        fields += f"offset = {draw(st.sampled_from([-40.0, 0.5, 273.15, 1e6]))!r}\n"
    regs = draw(st.lists(st.integers(0, 0xFFFF), min_size=n, max_size=n))
    if typ.startswith("f") and draw(st.booleans()):
        regs = draw(st.sampled_from([[0x7E00], [0x7FC0, 1], [0xFFF8, 0, 0, 1], [0x7C00],
                                     [0xFF80, 0], [0x8000, 0, 0, 0]]))[:n] + [0] * n
        regs = regs[:n]
    if draw(st.booleans()):
        raw = draw(st.integers(0, 0xFF if "8_" in typ else (1 << (16 * n)) - 1))
        ones = (1 << (8 if "8_" in typ else 16 * n)) - 1
        gone = f', {ones:#x} = "gone"' if raw != ones else ""
        fields += f'markers = {{ {raw:#x} = "offline"{gone} }}\n'
    return fields, regs


@settings(max_examples=600, deadline=None)
@given(numeric_points())
def test_c_decoder_matches_the_reference(case: tuple[str, list[int]]) -> None:
    fields, regs = case
    both(one(fields), regs)


@settings(max_examples=300, deadline=None)
@given(count=st.sampled_from([1, 2, 4]), data=st.data())
def test_bit_views_match(count: int, data: st.DataObject) -> None:
    regs = data.draw(st.lists(st.integers(0, 0xFFFF), min_size=count, max_size=count))
    order = data.draw(st.sampled_from(["ABCD", "CDAB", "BADC", "DCBA"]))
    bit = data.draw(st.integers(0, 16 * count - 1))
    shift = data.draw(st.integers(0, 16 * count - 1))
    width = data.draw(st.integers(1, 16 * count - shift))
    both(one(f'type = "bit"\ncount = {count}\norder = "{order}"\nbit = {bit}\n'), regs)
    both(one(f'type = "bits"\ncount = {count}\norder = "{order}"\nshift = {shift}\n'
             f'width = {width}\nmarkers = {{ 0 = "zero" }}\n'), regs)


@settings(max_examples=300, deadline=None)
@given(count=st.integers(1, 8), layout=st.sampled_from(["both", "high", "low"]),
       order=st.sampled_from(["ABCD", "BADC"]),
       encoding=st.sampled_from(["ascii", "latin-1", "utf-8"]),
       regs=st.lists(st.integers(0, 0xFFFF), min_size=8, max_size=8))
def test_strings_match(count: int, layout: str, order: str, encoding: str,
                       regs: list[int]) -> None:
    m = one(f'type = "string"\ncount = {count}\nstring_bytes = "{layout}"\n'
            f'order = "{order}"\nencoding = "{encoding}"\n')
    both(m, regs[:count])


def test_blocks_raw_and_coils_in_one_table() -> None:
    m = maps.loads(HEAD + """
[[block]]
name = "t"
first = 10
count = 5
stride = 2
type = "sm16"
scale = 0.1
markers = { 0xFFFF = "offline" }
[[point]]
name = "words"
address = 30
type = "raw"
count = 3
[[point]]
name = "big"
address = 20
type = "u64"
""")
    d = Decoder(m)
    assert (d.address, d.count, d.slots) == (10, 23, 7)
    regs = array("H", range(23))
    regs[0], regs[2], regs[10:14] = 0x8000 | 1896, 0xFFFF, array("H", [0xFFFF] * 4)
    got = d.read(regs)
    assert got == {"t": [-189.6, None, 0.4, 0.6, 0.8], "words": [20, 21, 22], "big": 2**64 - 1}
    assert d.states()["t"][1] == "offline"
    # into=: another set of buffers, the decoder's own untouched
    other = d.new_buffers()
    d.decode(array("H", [0] * 23), into=other)
    assert d.values(other)["big"] == 0
    assert d.values()["big"] == 2**64 - 1
    assert d.slot("big") == 6
    coils = maps.loads(HEAD + '[[point]]\nname = "run"\ntable = "coil"\naddress = 3\n'
                       '[[point]]\nname = "stop"\ntable = "coil"\naddress = 4\n')
    assert Decoder(coils).read([1, 0]) == {"run": True, "stop": False}


def test_the_decimal_power_rule_and_exact_integers() -> None:
    assert both(one('type = "i16"\nscale = 0.1\n'), [(-1896) & 0xFFFF])[0] == -189.6
    assert both(one('type = "u64"\n'), [0x0020, 0, 0, 1])[0] == 2**53 + 1
    assert both(one('type = "u64"\n'), [0xFFFF] * 4)[0] == 2**64 - 1
    assert both(one('type = "i64"\n'), [0x8000, 0, 0, 0])[0] == -(2**63)
    assert both(one('type = "f32"\n'), [0x7FC0, 0]) == (None, "nan")
    assert both(one('type = "string"\ncount = 2\n'), [0x41C3, 0]) == (None, "invalid_text")


def test_a_short_buffer_is_refused() -> None:
    d = Decoder(one('type = "u32"\n'))
    with pytest.raises(InvalidArgument, match="2 registers from 0 are needed, got 1"):
        d.decode([1])


@pytest.mark.parametrize("regs", [[0x10000, 0], [-1, 0], [None, 0]])
def test_a_register_outside_0_65535_is_refused_not_wrapped(regs: list[object]) -> None:
    m = one('type = "u32"\n')
    with pytest.raises(InvalidArgument):
        Decoder(m).decode(regs)  # type: ignore[arg-type]
    with pytest.raises(InvalidArgument):
        m.decode("p", regs)  # type: ignore[arg-type]
    assert m.decode("p", [0xFFFF, 0xFFFF]) == 0xFFFFFFFF


# -- Telegraf's inputs.modbus test table (plugins/inputs/modbus/modbus_test.go,
# TestRegisterHoldingRegisters): bytes on the wire, Telegraf's type and byte
# order as pymb names them, and the value Telegraf reads.

# Telegraf's table reads 0xFFFFFEBCF945F684 as 18446742686322259968: the value
# rounded through float64 (its low bits lost). pymb keeps it exact;
# test_telegraf_vectors checks that it rounds to Telegraf's number.
U64_EXACT = 0xFFFFFEBCF945F684
assert U64_EXACT == 18446742686322259588
assert float(U64_EXACT) == float(18446742686322259968)

TELEGRAF = [
    ("bits 0x180D bit 3", 'type = "bit"\nbit = 3\n', b"\x18\x0d", True),
    ("bits 0x180D bit 14", 'type = "bit"\nbit = 14\n', b"\x18\x0d", False),
    ("FIXED AB x0.1", 'type = "i16"\nscale = 0.1\n', b"\xff\xd6", -4.2),
    ("UFIXED BA x0.1", 'type = "u16"\norder = "BADC"\nscale = 0.1\n', b"\xd8\xff", 6549.6),
    ("FIXED ABCD x0.1", 'type = "i32"\nscale = 0.1\n', b"\xff\xff\xff\xd6", -4.2),
    ("UFIXED DCBA x0.001", 'type = "u32"\norder = "DCBA"\nscale = 0.001\n',
     b"\xd8\xff\xff\xff", 4294967.256),
    ("FIXED ABCDEFGH x1e-6", 'type = "i64"\nscale = 0.000001\n',
     b"\xff\xff\xff\xff\xff\xff\xff\xd6", -0.000042),
    ("UINT8L", 'type = "u8_lo"\n', b"\x18\x0d", 13),
    ("UINT8H", 'type = "u8_hi"\n', b"\x18\x0d", 24),
    ("INT8L", 'type = "i8_lo"\n', b"\x98\x8d", -115),
    ("INT8H", 'type = "i8_hi"\n', b"\x98\x8d", -104),
    ("UINT16 AB", 'type = "u16"\n', b"\xab\xcd", 43981),
    ("UINT16 BA", 'type = "u16"\norder = "BA"\n', b"\xab\xcd", 52651),
    ("INT16 AB", 'type = "i16"\n', b"\xab\xcd", -21555),
    ("INT16 BA", 'type = "i16"\norder = "BA"\n', b"\xab\xcd", -12885),
    ("INT32 ABCD", 'type = "i32"\n', b"\xaa\xbb\xcc\xdd", -1430532899),
    ("INT32 DCBA", 'type = "i32"\norder = "DCBA"\n', b"\xaa\xbb\xcc\xdd", -573785174),
    ("INT32 BADC", 'type = "i32"\norder = "BADC"\n', b"\xaa\xbb\xcc\xdd", -1146430004),
    ("INT32 CDAB", 'type = "i32"\norder = "CDAB"\n', b"\xaa\xbb\xcc\xdd", -857888069),
    ("INT32 x10", 'type = "i32"\nscale = 10\n', b"\x00\x00\xab\xcd", 439810.0),
    ("UINT32 ABCD", 'type = "u32"\n', b"\xaa\xbb\xcc\xdd", 2864434397),
    ("UINT32 DCBA", 'type = "u32"\norder = "DCBA"\n', b"\xaa\xbb\xcc\xdd", 3721182122),
    ("UINT32 BADC", 'type = "u32"\norder = "BADC"\n', b"\xaa\xbb\xcc\xdd", 3148537292),
    ("UINT32 CDAB", 'type = "u32"\norder = "CDAB"\n', b"\xaa\xbb\xcc\xdd", 3437079227),
    ("FLOAT32-IEEE ABCD", 'type = "f32"\n', b"\xaa\xbb\xcc\xdd",
     struct.unpack(">f", struct.pack(">f", -3.3360025e-13))[0]),
    ("INT64 ABCDEFGH", 'type = "i64"\n', b"\x00\x00\x01\x00\x00\x00\xab\xcd", 1099511671757),
    ("INT64 ABCDEFGH x10", 'type = "i64"\nscale = 10\n', b"\x00\x00\x01\x00\x00\x00\xab\xcd",
     10995116717570.0),
    ("INT64 HGFEDCBA", 'type = "i64"\norder = "HGFEDCBA"\n',
     b"\x84\xf6\x45\xf9\xbc\xfe\xff\xff", -1387387292028),
    ("INT64 BADCFEHG", 'type = "i64"\norder = "BADCFEHG"\n',
     b"\xff\xff\xbc\xfe\x45\xf9\x84\xf6", -1387387292028),
    ("INT64 GHEFCDAB", 'type = "i64"\norder = "GHEFCDAB"\n',
     b"\xf6\x84\xf9\x45\xfe\xbc\xff\xff", -1387387292028),
    ("UINT64 ABCDEFGH", 'type = "u64"\n', b"\x00\x00\x01\x00\x00\x00\xab\xcd", 1099511671757),
    ("UINT64 HGFEDCBA", 'type = "u64"\norder = "HGFEDCBA"\n',
     b"\x84\xf6\x45\xf9\xbc\xfe\xff\xff", U64_EXACT),
    ("UINT64 BADCFEHG", 'type = "u64"\norder = "BADCFEHG"\n',
     b"\xff\xff\xbc\xfe\x45\xf9\x84\xf6", U64_EXACT),
    ("UINT64 GHEFCDAB", 'type = "u64"\norder = "GHEFCDAB"\n',
     b"\xf6\x84\xf9\x45\xfe\xbc\xff\xff", U64_EXACT),
    ("FLOAT64-IEEE ABCDEFGH", 'type = "f64"\n', b"\xbf\x9c\x6a\x40\xc3\x47\x8f\x55",
     -0.02774907295123737),
    ("FLOAT64-IEEE positive", 'type = "f64"\n', b"\x3f\x9c\x6a\x40\xc3\x47\x8f\x55",
     0.02774907295123737),
    ("FLOAT64-IEEE HGFEDCBA", 'type = "f64"\norder = "HGFEDCBA"\n',
     b"\x55\x8f\x47\xc3\x40\x6a\x9c\xbf", -0.02774907295123737),
    ("FLOAT64-IEEE BADCFEHG", 'type = "f64"\norder = "BADCFEHG"\n',
     b"\x9c\xbf\x40\x6a\x47\xc3\x55\x8f", -0.02774907295123737),
    ("FLOAT64-IEEE GHEFCDAB", 'type = "f64"\norder = "GHEFCDAB"\n',
     b"\x8f\x55\xc3\x47\x6a\x40\xbf\x9c", -0.02774907295123737),
    ("FLOAT16-IEEE AB", 'type = "f16"\n', b"\xb8\x14", -0.509765625),
    ("FLOAT16-IEEE BA", 'type = "f16"\norder = "BA"\n', b"\x14\xb8", -0.509765625),
    ("STRING AB", 'type = "string"\ncount = 7\n', b"Modbus String\x00", "Modbus String"),
    ("STRING BA", 'type = "string"\ncount = 7\norder = "BADC"\n',
     b"oMbdsuS rtni\x00g", "Modbus String"),
]


@pytest.mark.parametrize(("fields", "wire", "expected"), [t[1:] for t in TELEGRAF],
                         ids=[t[0] for t in TELEGRAF])
def test_telegraf_vectors(fields: str, wire: bytes, expected: object) -> None:
    regs = list(struct.unpack(f">{len(wire) // 2}H", wire))
    value, state = both(one(fields), regs)
    assert state == "value"
    assert same(value, expected), (value, expected)


# -- libmodbus's own modbus_get_float_abcd/badc/cdab/dcba, through cffi's ABI mode

def _libmodbus() -> Any:
    from cffi import FFI  # type: ignore[import-untyped]

    ffi = FFI()
    ffi.cdef("float modbus_get_float_abcd(const uint16_t *src);"
             "float modbus_get_float_badc(const uint16_t *src);"
             "float modbus_get_float_cdab(const uint16_t *src);"
             "float modbus_get_float_dcba(const uint16_t *src);")
    return ffi, ffi.dlopen("libmodbus.so.5")


@pytest.mark.parametrize("order", ["ABCD", "BADC", "CDAB", "DCBA"])
def test_floats_read_as_libmodbus_reads_them(order: str) -> None:
    ffi, mb = _libmodbus()
    get = getattr(mb, f"modbus_get_float_{order.lower()}")
    m = maps.loads(HEAD + "".join(
        f'[[point]]\nname = "f{i}"\naddress = {2 * i}\ntype = "f32"\norder = "{order}"\n'
        for i in range(100)))
    d = Decoder(m)
    rng = random.Random(order)
    for _ in range(50):
        regs = array("H", [rng.randrange(0x10000) for _ in range(200)])
        got = d.read(regs)
        for i in range(100):
            theirs = float(get(ffi.new("uint16_t[2]", list(regs[2 * i:2 * i + 2]))))
            ours = got[f"f{i}"]
            if math.isnan(theirs):
                assert ours is None
            else:
                assert same(ours, theirs), (order, regs[2 * i:2 * i + 2], ours, theirs)


# -- pymodbus's conversions (big word order = ABCD, little = registers reversed, CDAB)

@settings(max_examples=400, deadline=None)
@given(typ=st.sampled_from(["i16", "u16", "i32", "u32", "i64", "u64", "f32", "f64"]),
       little=st.booleans(), data=st.data())
def test_pymodbus_conversions(typ: str, little: bool, data: st.DataObject) -> None:
    from pymodbus.client.mixin import ModbusClientMixin

    kind = {"i": "INT", "u": "UINT", "f": "FLOAT"}[typ[0]] + typ[1:]
    dtype = getattr(ModbusClientMixin.DATATYPE, kind)
    n = WIDTH[typ]
    regs = data.draw(st.lists(st.integers(0, 0xFFFF), min_size=n, max_size=n))
    theirs = ModbusClientMixin.convert_from_registers(
        regs, dtype, word_order="little" if little else "big")
    ours, _ = both(one(f'type = "{typ}"\norder = "{"CDAB" if little else "ABCD"}"\n'), regs)
    if isinstance(theirs, float) and math.isnan(theirs):
        assert ours is None
    else:
        assert ours == theirs


def test_a_bound_decode_is_decode_on_the_same_buffer_again() -> None:
    m = maps.loads(HEAD + "".join(f'[[point]]\nname = "v{i}"\naddress = {2 * i}\ntype = "f32"\n'
                                  for i in range(3)))
    d = Decoder(m)
    regs = array("H", struct.unpack(">6H", struct.pack(">3f", 1.5, -2.25, 1e3)))
    call = d.bind(regs)
    assert d.values() == {"v0": 1.5, "v1": -2.25, "v2": 1e3}  # bind decodes once
    regs[0:2] = array("H", struct.unpack(">2H", struct.pack(">f", 7.0)))
    assert call() == 3
    assert d.values() == {"v0": 7.0, "v1": -2.25, "v2": 1e3}
    assert d.read(regs) == d.values()
    with pytest.raises(BufferError):
        regs.append(0)  # held by the call: its size cannot change under it
    with pytest.raises(InvalidArgument, match="array"):
        d.bind([0] * 6)  # type: ignore[arg-type]
    with pytest.raises(InvalidArgument, match="6 registers"):
        d.bind(array("H", [0] * 5))
