"""The loader's messages say what is wrong in the map's own terms: a bits
field that runs out of its register, an order with the letters it may use."""

from __future__ import annotations

import pytest

from pymb import maps

HEAD = 'schema = "pymb.map/1"\n[device]\nid = "t"\ntable = "holding"\n'


def _message(body: str) -> str:
    with pytest.raises(maps.MapError) as info:
        maps.loads(HEAD + body, source="t.toml")
    return str(info.value)


def test_a_bits_field_past_its_register_says_shift_plus_width() -> None:
    body = '[[point]]\nname = "m"\naddress = 0\ntype = "bits"\nshift = {}\nwidth = {}\n'
    assert _message(body.format(14, 3)) == (
        "t.toml: point 'm': key 'width': shift + width (14 + 3 = 17) exceeds the register's "
        "16 bits")
    assert maps.loads(HEAD + body.format(14, 2)).points["m"].width == 2
    assert "width must be a whole number 1..16, got 17" in _message(body.format(0, 17))


@pytest.mark.parametrize(("typ", "letters"), [("f32", "4 letters ABCD"),
                                              ("f64", "8 letters ABCDEFGH")])
def test_a_bad_order_names_the_letters(typ: str, letters: str) -> None:
    body = f'[[point]]\nname = "f"\naddress = 0\ntype = "{typ}"\norder = "AB"\n'
    assert _message(body) == ("t.toml: point 'f': key 'order': order 'AB' is not ABCD, CDAB, "
                              f"BADC, DCBA or a permutation of the {letters}")
