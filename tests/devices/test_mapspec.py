"""The device syntax for a map's id, and recognising a device by its map's
identify rules, with no I/O (the questions are answered from registers)."""

from __future__ import annotations

import struct
from collections.abc import Callable

import pytest

from pymb import maps
from pymb.devices.mapspec import match_map, parse_map_device
from pymb.errors import InvalidArgument

BASE = """schema = "pymb.map/1"
[device]
id = "{id}"
table = "input"
[device.options]
phases = {{ default = 3, values = [1, 3] }}
[[point]]
name = "voltage_v"
address = 0
type = "f32"
[[point]]
name = "l2_voltage_v"
address = 2
type = "f32"
[[identify]]
point = "voltage_v"
range = [80.0, 300.0]
"""
SECOND = """[[identify]]
point = "l2_voltage_v"
range = [80.0, 300.0]
"""


def device(voltages: list[float]) -> Callable[[int, int, bytes], bytes | int | None]:
    regs = [r for v in voltages for r in struct.unpack(">HH", struct.pack(">f", v))]

    def ask(address: int, function: int, data: bytes) -> bytes | int | None:
        first, count = struct.unpack(">HH", data)
        if function != 4 or first + count > len(regs):
            return 2
        return bytes((2 * count,)) + struct.pack(f">{count}H", *regs[first:first + count])

    return ask


def test_the_map_with_most_rules_that_hold_wins() -> None:
    one = maps.loads(BASE.format(id="one-phase"))
    three = maps.loads(BASE.format(id="three-phase") + SECOND)
    known = {"one-phase": one, "three-phase": three}
    assert match_map(device([230.0, 231.0]), 1, known) == (
        "three-phase", "voltage_v 230, l2_voltage_v 231")
    assert match_map(device([230.0]), 1, known) == (
        "one-phase", "voltage_v 230")
    assert match_map(device([12.0, 230.0]), 1, known) is None
    twin = maps.loads(BASE.format(id="twin"))
    got = match_map(device([230.0]), 1, {"one-phase": one, "twin": twin})
    assert got is not None
    assert got[0] == "one-phase"
    assert got[1].endswith("(the identify rules of twin hold too)")


def test_the_device_syntax_for_a_map() -> None:
    m = maps.loads(BASE.format(id="meter"))
    known = {"meter": m}
    t = parse_map_device("meter:7,phases=1,name=main", known)
    assert t is not None
    assert (t.address, t.name, dict(t.options), t.map.options["phases"]) == (7, "main",
                                                                             {"phases": 1}, 1)
    assert t.spec == "meter:7,phases=1"
    assert parse_map_device("coolpro:40", known) is None
    with pytest.raises(InvalidArgument, match=r"did you mean 'phases'"):
        parse_map_device("meter,phase=1", known)
    with pytest.raises(InvalidArgument, match="phases given twice"):
        parse_map_device("meter,phases=1,phases=3", known)
    with pytest.raises(InvalidArgument, match="name given twice"):
        parse_map_device("meter,name=a,name=b", known)
    with pytest.raises(InvalidArgument, match=r"address must be 1\.\.247"):
        parse_map_device("meter:0", known)
    with pytest.raises(InvalidArgument, match="whole number"):
        parse_map_device("meter:x", known)
