"""A ``string`` point's one marker, ``0``: the empty text (first character
NUL, SunSpec's all-NUL "not implemented") is no value with the marker's
state, in the C decoder as in the Python codec; any other marker on a
string is a load error naming the key."""

from __future__ import annotations

import pytest

from pymb import maps
from pymb.maps import Decoder
from pymb.maps.codec import decode

HEAD = 'schema = "pymb.map/1"\n[device]\nid = "t"\ntable = "holding"\n'
TEXT = HEAD + ('[[point]]\nname = "s"\naddress = 0\ntype = "string"\ncount = 3\n{}\n'
               '[[point]]\nname = "b"\naddress = 3\ntype = "string"\ncount = 2\n'
               'string_bytes = "low"\n{}\n[[point]]\nname = "c"\naddress = 5\n'
               'type = "string"\ncount = 2\nstring_bytes = "low"\n{}\n')
MARKED = 'markers = { 0 = "not_implemented" }'


@pytest.mark.parametrize(("regs", "texts"), [
    ([0, 0, 0, 0, 0, 0, 0], (None, None, None)),
    ([0x0041, 0x4200, 0, 0x0041, 0, 0x0042, 0x4200], (None, "A", "B")),
    ([0x4142, 0x2020, 0, 0x4100, 0x0041, 0, 0], ("AB  ", None, None)),
    ([0x4100, 0x4343, 0x4343, 0x0020, 0x2000, 0x0042, 0], ("A", " ", "B")),
])
def test_the_empty_text_takes_the_marker(regs: list[int],
                                         texts: tuple[str | None, ...]) -> None:
    m = maps.loads(TEXT.format(MARKED, MARKED, ""))
    names = ("s", "b", "c")
    expected = {"s": texts[0], "b": texts[1], "c": texts[2] or ""}  # c has no marker
    assert Decoder(m).read(regs) == expected
    for name in names:
        p = m.points[name]
        value = expected[name]
        assert decode(p, regs[p.address:]) == (value, "value" if value is not None
                                                   else "not_implemented"), name
    plain = Decoder(maps.loads(TEXT.format("", "", ""))).read(regs)
    assert plain == {n: t or "" for n, t in zip(names, texts, strict=True)}


@pytest.mark.parametrize("markers", ['{ 1 = "x" }', '{ 0 = "a", 0xFFFF = "b" }',
                                     '{ "0x00xx" = "x" }'])
def test_a_string_takes_no_other_marker(markers: str) -> None:
    with pytest.raises(maps.MapError) as info:
        maps.loads(TEXT.format(f"markers = {markers}", "", ""), source="t.toml")
    assert info.value.key == "markers"
    assert "a string's only marker is 0, the empty text" in str(info.value)
