"""A block's channels are columns ``name_N`` in exports (``--layout wide``)
and InfluxDB fields: a point of that name would share the column with the
channel (one of the two lost), so the map is refused when it loads."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import run_pymb

from pymb import maps

MAP = """schema = "pymb.map/1"
[device]
id = "col-dev"
table = "holding"
[device.options]
sensors = {{ default = 2, min = 1, max = 8 }}
[[block]]
name = "t"
first = 0
count = "sensors"
type = "u16"
[[point]]
name = "{name}"
address = 10
type = "u16"
"""


def test_a_point_named_as_a_block_channel_is_refused() -> None:
    with pytest.raises(maps.MapError) as info:
        maps.loads(MAP.format(name="t_2"), source="c.toml")
    e = info.value
    assert (e.source, e.point, e.key) == ("c.toml", "t_2", "name")
    assert str(e) == ("c.toml: point 't_2': key 'name': the name 't_2' is channel 2 of block "
                      "'t' in exports and InfluxDB (t_1..t_2); rename the point or the block")


def test_names_beside_a_block_that_do_not_collide_load() -> None:
    for name in ("t_0", "t_3", "t1", "temp_1", "t_state"):
        m = maps.loads(MAP.format(name=name))
        assert name in m.points
    # ... unless an option gives the block that channel
    m = maps.loads(MAP.format(name="t_3"))
    with pytest.raises(maps.MapError, match=r"'t_3' is channel 3 of block 't'"):
        m.configure({"sensors": 3})


def test_a_point_named_as_the_influx_state_field_of_another_is_refused() -> None:
    for name, what in (("t_2_state", "channel 2 of block 't'"), ("x_state", "point 'x'")):
        body = MAP.format(name="x") + f'[[point]]\nname = "{name}"\naddress = 11\ntype = "u16"\n'
        with pytest.raises(maps.MapError) as info:
            maps.loads(body, source="c.toml")
        assert str(info.value) == (f"c.toml: point '{name}': key 'name': the name '{name}' is "
                                   f"the InfluxDB field that says why {what} has no value; "
                                   "rename the point")


def test_map_check_refuses_it_in_one_line(tmp_path: Path) -> None:
    f = tmp_path / "col.toml"
    f.write_text(MAP.format(name="t_1"))
    r = run_pymb("map", "check", str(f))
    assert r.returncode == 2, r.stdout
    assert r.stderr.count("\n") == 1, r.stderr
    assert "point 't_1': key 'name': the name 't_1' is channel 1 of block 't'" in r.stderr
