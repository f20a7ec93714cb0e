"""Two load rules of the map format: ``flags`` keys are bit numbers in
decimal (a key written as a mask, ``0x0008``, is refused with the bit it
meant), and points that share registers must be views of one another."""

from __future__ import annotations

import pytest

from pymb import maps

HEAD = 'schema = "pymb.map/1"\n[device]\nid = "t"\ntable = "holding"\n'


def load(points: str) -> maps.Map:
    return maps.loads(HEAD + points, source="dev.toml")


def refused(points: str) -> str:
    with pytest.raises(maps.MapError) as e:
        load(points)
    msg = str(e.value)
    assert msg.startswith("dev.toml: point ")
    assert "\n" not in msg
    return msg


WORD = '[[point]]\nname = "eta"\naddress = 0\ntype = "{t}"\nflags = {{ {k} = "alarm" }}\n'


@pytest.mark.parametrize(("key", "meant"), [("0x0008", 3), ("0x8000", 15), ("0b100", 2),
                                            ("0X0001", 0), ("0o20", 4)])
def test_a_mask_written_as_a_flags_key_names_the_bit_it_meant(key: str, meant: int) -> None:
    msg = refused(WORD.format(t="u16", k=key))
    assert f"{key} is a mask" in msg
    assert f'write {meant} = "alarm"' in msg


def test_flags_keys_are_decimal_bit_numbers() -> None:
    m = load('[[point]]\nname = "eta"\naddress = 0\ntype = "u32"\n'
             'flags = { 0 = "ready", 3 = "fault", 31 = "top" }\n')
    assert m.points["eta"].flags == {0: "ready", 3: "fault", 31: "top"}
    assert m.flag_names("eta", 0x80000009) == ["ready", "fault", "top"]
    assert "a mask of bits 1, 2" in refused(WORD.format(t="u16", k="0x0006"))
    msg = refused(WORD.format(t="u16", k="16"))
    assert "16 is no bit of a u16 (bits 0..15); if 16 is a mask, it is bit 4" in msg
    assert "not a bit number" in refused(WORD.format(t="u16", k='"x"'))
    assert "no bit of a u16 (bits 0..15)" in refused(WORD.format(t="u16", k="20"))


def test_full_width_points_of_different_types_on_one_register_are_refused() -> None:
    msg = refused('[[point]]\nname = "current_a"\naddress = 10\ntype = "f32"\n'
                  '[[point]]\nname = "power_w"\naddress = 10\ntype = "i32"\nscale = 0.1\n')
    assert "'power_w'" in msg
    assert "overlaps 'current_a' (holding 10..11)" in msg
    assert 'view_of = "current_a"' in msg
    assert "overlaps" in refused('[[point]]\nname = "a"\naddress = 10\ntype = "u16"\n'
                                 '[[point]]\nname = "b"\naddress = 10\ntype = "i16"\n')
    assert "overlaps" in refused('[[point]]\nname = "a"\naddress = 10\ntype = "u32"\n'
                                 '[[point]]\nname = "b"\naddress = 10\ntype = "u32"\n'
                                 'order = "CDAB"\n')


def test_views_of_one_another_are_allowed() -> None:
    m = load('[[point]]\nname = "energy"\naddress = 10\ntype = "u32"\n'
             '[[point]]\nname = "energy_low"\naddress = 11\ntype = "u16"\nview_of = "energy"\n'
             '[[point]]\nname = "as_float"\naddress = 10\ntype = "f32"\nview_of = "energy"\n'
             '[[point]]\nname = "eta"\naddress = 20\ntype = "u16"\n'
             '[[point]]\nname = "state"\naddress = 20\ntype = "u16"\nmask = 0x006F\n'
             '[[point]]\nname = "words"\naddress = 10\ntype = "raw"\ncount = 2\n')
    d = maps.Decoder(m, ["energy", "energy_low", "as_float"])
    assert d.read([0x4366, 0x8000]) == {"energy": 0x43668000, "energy_low": 0x8000,
                                        "as_float": 230.5}
    assert "share no register" in refused(
        '[[point]]\nname = "a"\naddress = 10\ntype = "u16"\n'
        '[[point]]\nname = "b"\naddress = 12\ntype = "u16"\nview_of = "a"\n')
    assert "view_of names no point 'c'" in refused(
        '[[point]]\nname = "a"\naddress = 10\ntype = "u16"\n'
        '[[point]]\nname = "b"\naddress = 10\ntype = "i16"\nview_of = "c"\n')


def test_every_shipped_map_keeps_the_rules() -> None:
    for i in maps.builtin_ids():
        assert maps.builtin(i).id == i
