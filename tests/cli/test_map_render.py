"""A map device's reading as the commands print it: one line per point, a
block one line per channel, names of values and flags, states for no value."""

from __future__ import annotations

import json

from pymb import maps
from pymb.commands.mapcli import map_json, render_map

MAP = """schema = "pymb.map/1"
[device]
id = "render-test"
table = "holding"

[[point]]
name = "mode"
address = 0
type = "u16"
values = { 0 = "stop", 1 = "run" }

[[point]]
name = "alarms"
address = 1
type = "u16"
flags = { 0 = "overtemp", 3 = "fan" }

[[point]]
name = "flow_lpm"
address = 2
type = "u16"
scale = 0.1
precision = 2
unit = "l/min"

[[block]]
name = "temp_c"
first = 10
count = 2
type = "sm16"
scale = 0.1
unit = "°C"
markers = { 0xFFFF = "offline" }
"""


def test_a_reading_as_lines_and_as_json() -> None:
    m = maps.loads(MAP)
    values = {"mode": 1, "alarms": 0b1001, "flow_lpm": 12.5, "temp_c": [21.5, None]}
    states = {"mode": "value", "alarms": "value", "flow_lpm": "value",
              "temp_c": ["value", "offline"]}
    assert render_map(m, values, states).splitlines() == [
        "mode       1 (run)",
        "alarms     0x0009 (overtemp, fan)",
        "flow_lpm   12.50 l/min",
        "temp_c[1]  21.5 °C",
        "temp_c[2]  offline",
    ]
    doc = map_json({**values, "flow_lpm": float("nan")}, states)
    assert doc["values"]["flow_lpm"] is None
    assert json.loads(json.dumps(doc))["states"]["temp_c"] == ["value", "offline"]
