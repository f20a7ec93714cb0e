"""Every mistake in a map file is one MapError naming the file, the point and
the key, with a did-you-mean; never a traceback from the loader."""

from __future__ import annotations

from pathlib import Path

import pytest

from pymb import ModbusError, maps

HEAD = """schema = "pymb.map/1"
[device]
id = "t"
table = "holding"
[groups]
fast = { interval = 1.0 }
"""


def load(body: str, head: str = HEAD) -> maps.Map:
    return maps.loads(head + body, source="t.toml")


def fails(body: str, *expected: str, head: str = HEAD) -> maps.MapError:
    with pytest.raises(maps.MapError) as info:
        load(body, head)
    message = str(info.value)
    assert message.startswith("t.toml: "), message
    assert "\n" not in message
    for text in expected:
        assert text in message, message
    return info.value


def test_map_error_is_a_modbus_error_and_a_value_error() -> None:
    e = fails('[[point]]\nname = "a"\naddress = 0\ntype = "u16"\nscle = 2\n',
              "point 'a'", "'scle'", "did you mean 'scale'?")
    assert isinstance(e, ModbusError)
    assert isinstance(e, ValueError)
    assert (e.source, e.point, e.key) == ("t.toml", "a", "scle")


@pytest.mark.parametrize(("body", "expected"), [
    # unknown keys, sections, types, with the nearest known one
    ('[[point]]\nname = "a"\naddress = 0\ntype = "flaot32"\n', ("'type'", "did you mean 'f32'")),
    ('[[point]]\nname = "a"\naddress = 0\ntype = "u16"\ngruop = "fast"\n',
     ("did you mean 'group'",)),
    ('[[pointt]]\nname = "a"\n', ("unknown key 'pointt'", "did you mean 'point'")),
    ('[[point]]\nname = "a"\naddress = 0\ntype = "u16"\ngroup = "fsat"\n',
     ("point 'a'", "'group'", "did you mean 'fast'")),
    ('[[point]]\nname = "a"\naddress = 0\ntype = "u16"\ntable = "holdings"\n',
     ("did you mean 'holding'",)),
    ('[[point]]\nname = "a"\naddress = 0\ntype = "u16"\nkind = "guage"\n',
     ("did you mean 'gauge'",)),
    ('[[block]]\nname = "a"\naddress = 0\ntype = "u16"\n', ("'address'", "`first`")),
    ('[[point]]\nname = "a"\nfirst = 0\ntype = "u16"\n', ("'first'", "[[block]]")),
    # required fields and their forms
    ('[[point]]\nname = "a"\ntype = "u16"\n', ("point 'a'", "'address'", "required")),
    ('[[point]]\nname = "a"\naddress = 0\n', ("'type'", "required")),
    ('[[point]]\nname = "A b"\naddress = 0\ntype = "u16"\n', ("'name'", "snake_case")),
    ('[[point]]\nname = "a..b"\naddress = 0\ntype = "u16"\n', ("'name'", "snake_case")),
    ('[[point]]\nname = "s"\naddress = 0\ntype = "string"\n', ("'count'", "required")),
    ('[[point]]\nname = "s"\naddress = 0\ntype = "raw"\ncount = 126\n', ("'count'", "1..125")),
    ('[[point]]\nname = "a"\naddress = 0\ntype = "u32"\ncount = 2\n', ("'count'", "[[block]]")),
    ('[[point]]\nname = "a"\naddress = 0\ntype = "bit"\n', ("'bit'", "required")),
    ('[[point]]\nname = "a"\naddress = 0\ntype = "bit"\nbit = 16\n', ("'bit'", "0..15")),
    ('[[point]]\nname = "a"\naddress = 0\ntype = "bits"\nshift = 12\nwidth = 5\n',
     ("'width'", "shift + width (12 + 5 = 17) exceeds the register's 16 bits")),
    # keys that do not apply to the type
    ('[[point]]\nname = "a"\naddress = 0\ntype = "string"\ncount = 2\nscale = 2\n',
     ("'scale'", "numeric")),
    ('[[point]]\nname = "a"\naddress = 0\ntype = "u16"\nencoding = "ascii"\n',
     ("'encoding'", "string")),
    # a bit number on a field of bits, as a newcomer writes it: say what the field takes
    ('[[point]]\nname = "a"\naddress = 0\ntype = "bits"\nbit = 4\nwidth = 3\n',
     ("'bit'", "bit applies to bit points only, not bits; a bits field is given by shift "
               "and width")),
    ('[[point]]\nname = "a"\naddress = 0\ntype = "u16"\naccess = "rw"\n'
     'values = { 0 = "stop", 1 = "stop" }\n', ("'values'", "'stop' names both 0 and 1")),
    ('[[point]]\nname = "a"\naddress = 0\ntype = "string"\ncount = 2\naccess = "rw"\n'
     'valid = [0, 9]\n', ("'valid'", "numeric points only, not string")),
    ('[[point]]\nname = "a"\naddress = 0\ntype = "raw"\ncount = 2\nvalid = [0, 9]\n',
     ("'valid'", "not raw")),
    ('[[point]]\nname = "a"\naddress = 0\ntype = "f32"\nvalues = { 0 = "x" }\n',
     ("'values'", "integer")),
    ('[[point]]\nname = "a"\ntable = "coil"\naddress = 0\ntype = "u16"\n', ("'type'", "bool")),
    ('[[point]]\nname = "a"\naddress = 0\ntype = "bool"\n', ("'type'", "coil")),
    ('[[point]]\nname = "a"\ntable = "input"\naddress = 0\ntype = "u16"\naccess = "rw"\n',
     ("'access'", "read-only")),
    # values out of range
    ('[[point]]\nname = "a"\naddress = 65535\ntype = "u32"\n', ("'address'", "65535")),
    ('[[point]]\nname = "a"\naddress = 0\ntype = "u16"\nmarkers = { 0x10000 = "x" }\n',
     ("'markers'", "0x10000")),
    ('[[point]]\nname = "a"\naddress = 0\ntype = "u16"\nmarkers = { abc = "x" }\n',
     ("'markers'", "'abc'")),
    ('[[point]]\nname = "a"\naddress = 0\ntype = "u16"\norder = "ABCE"\n', ("'order'",)),
    ('[[point]]\nname = "a"\naddress = 0\ntype = "u32"\norder = "BA"\n', ("'order'",)),
    ('[[point]]\nname = "a"\naddress = 0\ntype = "u16"\nscale = 0\n', ("'scale'",)),
    ('[[point]]\nname = "a"\naddress = 0\ntype = "u16"\nvalid = [5, 1]\n', ("'valid'",)),
    ('[[point]]\nname = "a"\naddress = 0\ntype = "u16"\naccess = "rw"\nexample = 70000\n',
     ("'example'", "range")),
    ('[[block]]\nname = "a"\nfirst = 0\ncount = 1001\ntype = "u16"\n', ("'count'", "1..1000")),
    ('[[block]]\nname = "a"\nfirst = 0\ncount = 2\nstride = 1\ntype = "u32"\n',
     ("'stride'", "2..")),
    ('[[block]]\nname = "a"\nfirst = 0\ncount = "chanels"\ntype = "u16"\n',
     ("'count'", "no option 'chanels'")),
    # the overlap rule and unique names
    ('[[point]]\nname = "a"\naddress = 0\ntype = "u32"\n[[point]]\nname = "b"\naddress = 1\n'
     'type = "u16"\n', ("point 'b'", "overlaps", "'a'")),
    ('[[block]]\nname = "a"\nfirst = 0\ncount = 10\ntype = "u16"\n[[point]]\nname = "b"\n'
     'address = 9\ntype = "u32"\n', ("overlaps", "channel 10")),
    ('[[point]]\nname = "a"\naddress = 0\ntype = "u16"\n[[point]]\nname = "a"\naddress = 1\n'
     'type = "u16"\n', ("'name'", "twice")),
    # identify
    ('[[point]]\nname = "a"\naddress = 0\ntype = "u16"\n[[identify]]\npoint = "b"\n'
     'equals = 1\n', ("[[identify]] number 1", "no point 'b'", "known: a")),
    ('[[point]]\nname = "a"\naddress = 0\ntype = "u16"\n[[identify]]\npoint = "a"\n'
     'regex = "^x"\n', ("regex", "string point")),
    ('', ("no [[point]]",)),
])
def test_mistakes(body: str, expected: tuple[str, ...]) -> None:
    fails(body, *expected)


@pytest.mark.parametrize(("head", "expected"), [
    ('schema = "pymb.map/2"\n[device]\nid = "t"\n', ("'schema'", "pymb.map/1")),
    ('[device]\nid = "t"\n', ("schema",)),
    ('schema = "pymb.map/1"\n[device]\nid = "T x"\n', ("'id'",)),
    ('schema = "pymb.map/1"\n[device]\nid = "t"\nmodle = "x"\n', ("did you mean 'model'",)),
    ('schema = "pymb.map/1"\n[device]\nid = "t"\norder = "ABDC"\n', ("'order'",)),
    ('schema = "pymb.map/1"\n[device]\nid = "t"\naddress_base = 2\n', ("'address_base'",)),
    ('schema = "pymb.map/1"\n[device]\nid = "t"\naddresses = [1, 256]\n', ("'addresses'",)),
    ('schema = "pymb.map/1"\n[device]\nid = "t"\ndefault_address = 9\naddresses = [1, 5]\n',
     ("'default_address'", "1..5")),
    ('schema = "pymb.map/1"\n[device]\nid = "t"\n[device.limits]\nmax_registers = 126\n',
     ("'max_registers'", "1..125")),
    ('schema = "pymb.map/1"\n[device]\nid = "t"\n[device.limits]\nmax_regs = 10\n',
     ("did you mean 'max_registers'",)),
    ('schema = "pymb.map/1"\n[device]\nid = "t"\n[device.limits]\nreadable = { inptu = [] }\n',
     ("'readable'", "did you mean 'input'",)),
    ('schema = "pymb.map/1"\n[device]\nid = "t"\n[device.timing]\nturnaroud = 0.1\n',
     ("did you mean 'turnaround'",)),
    ('schema = "pymb.map/1"\n[device]\nid = "t"\n[device.timing]\nresponse_timeout = 0\n',
     ("'response_timeout'",)),
    ('schema = "pymb.map/1"\n[device]\nid = "t"\n[device.options]\nchannels = "x"\n',
     ("'channels'", "int or a float")),
    ('schema = "pymb.map/1"\n[device]\nid = "t"\n[groups]\nfast = { intervall = 1 }\n',
     ("did you mean 'interval'",)),
    ('schema = "pymb.map/1"\n[device\nid = "t"\n', ("not valid TOML",)),
])
def test_section_mistakes(head: str, expected: tuple[str, ...]) -> None:
    fails('[[point]]\nname = "a"\naddress = 0\ntype = "u16"\n', *expected, head=head)


def test_address_base_one_puts_the_number_minus_one_on_the_wire() -> None:
    m = load('[[point]]\nname = "a"\naddress = 1\ntype = "u16"\n',
             HEAD.replace('table = "holding"', 'table = "holding"\naddress_base = 1'))
    assert m.points["a"].address == 0
    fails('[[point]]\nname = "a"\naddress = 0\ntype = "u16"\n', "'address'", "1..65536",
          head=HEAD.replace('table = "holding"', 'table = "holding"\naddress_base = 1'))


def test_views_may_overlap_their_register() -> None:
    m = load('[[point]]\nname = "status"\naddress = 0\ntype = "u16"\n'
             '[[point]]\nname = "fault"\naddress = 0\ntype = "bit"\nbit = 3\n'
             '[[point]]\nname = "hi"\naddress = 0\ntype = "u8_hi"\n'
             '[[point]]\nname = "total"\naddress = 4\ntype = "u32"\n'
             '[[point]]\nname = "total_words"\naddress = 4\ntype = "raw"\ncount = 2\n'
             '[[point]]\nname = "low_flag"\naddress = 5\ntype = "bits"\nshift = 2\nwidth = 3\n')
    assert list(m.points) == ["status", "fault", "hi", "total", "total_words", "low_flag"]


def test_a_file_that_cannot_be_read_is_a_map_error(tmp_path: Path) -> None:
    with pytest.raises(maps.MapError, match=r"nope\.toml: cannot read the map"):
        maps.load(tmp_path / "nope.toml")
    bad = tmp_path / "bad.toml"
    bad.write_bytes(b"\xff\xfe")
    with pytest.raises(maps.MapError, match=r"bad\.toml"):
        maps.load(bad)


def test_options_in_the_device_syntax() -> None:
    hub = maps.builtin("hub")
    assert hub.options == {"channels": 100, "humidity_unit": 0.1}
    h = hub.configure({"channels": "50", "humidity_unit": "1"})
    hum = h.points["humidity_pct"]
    assert (hum.channels, hum.scale, dict(hum.markers)) == (50, 1.0,
                                                             {0xFFFF: "offline", 0xFF: "no_sensor"})
    assert hub.points["humidity_pct"].markers[0x8000] == "no_sensor"
    with pytest.raises(maps.MapError, match="no option 'chanels'; did you mean 'channels'"):
        hub.configure(chanels=5)
    with pytest.raises(maps.MapError, match=r"'channels' must be 1\.\.100"):
        hub.configure(channels=101)
    with pytest.raises(maps.MapError, match="'channels' must be a whole number"):
        hub.configure(channels="many")
    with pytest.raises(maps.MapError, match=r"'humidity_unit' must be one of 1, 0\.1"):
        hub.configure(humidity_unit=0.5)


def test_unknown_point_and_builtin_names() -> None:
    with pytest.raises(maps.MapError, match="did you mean 'uptime_s'"):
        maps.builtin("coolpro").decode("uptime", [0, 0])
    with pytest.raises(maps.MapError, match="did you mean 'coolpro'"):
        maps.builtin("colpro")
    assert {"coolpro", "hub"} <= set(maps.builtin_ids())



@pytest.mark.parametrize(("count", "said"), [("3", "3"), ("2.0", "2.0"), ("true", "True"),
                                             ('"2"', "'2'")])
def test_a_bit_view_spans_1_2_or_4_whole_registers(count: str, said: str) -> None:
    bit = '[[point]]\nname = "a"\naddress = 0\ntype = "bit"\nbit = 3\n'
    fails(f"{bit}count = {count}\n", "point 'a'", "'count'",
          f"must be 1, 2 or 4 registers, got {said}")
    assert load(f"{bit}count = 2\n").points["a"].count == 2
