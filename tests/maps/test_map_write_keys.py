"""The map keys of writes: ``max_writes_per_hour`` on a point or in
``[device]`` (for every writable point), and ``[device.limits]``
``write_multiple`` and ``mask_write``. Mistakes are MapErrors naming the
file, the point and the key."""

from __future__ import annotations

import pytest

from pymb import maps
from pymb.errors import InvalidArgument

HEAD = """schema = "pymb.map/1"
[device]
id = "budgeted"
table = "holding"
{device}
[device.limits]
{limits}
[[point]]
name = "setpoint"
address = 0
type = "u16"
access = "rw"
{point}
[[point]]
name = "other_setpoint"
address = 1
type = "u16"
access = "rw"
[[point]]
name = "reading"
address = 2
type = "u16"
"""


def load(device: str = "", limits: str = "", point: str = "") -> maps.Map:
    return maps.loads(HEAD.format(device=device, limits=limits, point=point), source="b.toml")


def test_defaults_no_budget_fc06_and_read_modify_write() -> None:
    m = load()
    assert m.points["setpoint"].max_writes_per_hour is None
    assert m.device.max_writes_per_hour is None
    assert (m.limits.write_multiple, m.limits.mask_write) == ("auto", False)


def test_a_points_budget_and_the_devices_for_every_other_writable_point() -> None:
    m = load(device="max_writes_per_hour = 10", point="max_writes_per_hour = 3")
    assert m.device.max_writes_per_hour == 10
    assert m.points["setpoint"].max_writes_per_hour == 3
    assert m.points["other_setpoint"].max_writes_per_hour == 10
    assert m.points["reading"].max_writes_per_hour is None  # read-only: nothing to count


def test_limits_write_multiple_always_and_mask_write() -> None:
    m = load(limits='write_multiple = "always"\nmask_write = true')
    assert (m.limits.write_multiple, m.limits.mask_write) == ("always", True)


@pytest.mark.parametrize(("where", "text", "point", "key"), [
    ("point", "max_writes_per_hour = 0", "setpoint", "max_writes_per_hour"),
    ("point", 'max_writes_per_hour = "3"', "setpoint", "max_writes_per_hour"),
    ("device", "max_writes_per_hour = -1", None, "max_writes_per_hour"),
    ("device", "max_writes_per_hour = 2.5", None, "max_writes_per_hour"),
    ("limits", 'write_multiple = "never"', None, "write_multiple"),
    ("limits", 'mask_write = "yes"', None, "mask_write"),
    ("limits", "mask_writes = true", None, "mask_writes"),
])
def test_mistakes_are_map_errors_naming_the_key(where: str, text: str, point: str | None,
                                                key: str) -> None:
    with pytest.raises(maps.MapError) as info:
        load(**{where: text})
    assert (info.value.source, info.value.point, info.value.key) == ("b.toml", point, key)
    assert key in str(info.value)


def test_a_budget_on_a_read_only_point_is_a_mistake() -> None:
    text = HEAD.format(device="", limits="", point="").replace(
        'type = "u16"\n"""', 'type = "u16"\n').rstrip() + "\nmax_writes_per_hour = 5\n"
    with pytest.raises(maps.MapError) as info:
        maps.loads(text, source="b.toml")
    assert (info.value.point, info.value.key) == ("reading", "max_writes_per_hour")
    assert "writable points" in str(info.value)


def test_encoding_an_unknown_point_is_an_invalid_argument_with_the_closest_name() -> None:
    m = maps.builtin("coolpro")
    with pytest.raises(InvalidArgument, match="did you mean 'output_voltage_v'"):
        m.encode("output_voltag", 1)
