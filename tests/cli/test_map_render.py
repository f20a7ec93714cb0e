"""A map device's reading as the commands print it: one line per point, a
block one line per channel, names of values and flags, states for no value."""

from __future__ import annotations

import json
from pathlib import Path

from conftest import run_pymb

from pymb import maps
from pymb.commands.maptext import map_json, render_map
from pymb.sim import SimulatorProcess

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


DIGITS = """schema = "pymb.map/1"
[device]
id = "digits-meter"
default_address = 1
table = "input"

[[point]]
name = "energy_kwh"
address = 0
type = "f32"
unit = "kWh"
example = 123456.7

[[point]]
name = "voltage_v"
address = 2
type = "i32"
scale = 0.1
unit = "V"
example = 214748364.7

[[point]]
name = "current_a"
address = 4
type = "u16"
scale = 0.001
unit = "A"
example = 1.5

[[point]]
name = "frequency_hz"
address = 5
type = "f32"
precision = 2
unit = "Hz"
example = 50
"""


def test_numbers_show_the_digits_of_their_type_scale_or_precision(tmp_path: Path) -> None:
    """As a user reads a meter: an f32 energy counter keeps its decimal, an
    i32 overflow pattern with scale 0.1 is not written with an exponent, a
    scale of 0.001 gives three decimals, ``precision`` its own."""
    path = tmp_path / "digits.toml"
    path.write_text(DIGITS)
    with SimulatorProcess(["--map", str(path), "digits-meter:1"], quiet=True) as sim:
        r = run_pymb("read", "--map", str(path), "digits-meter:1", "--port", sim.port)
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines() == [
        "energy_kwh    123456.7 kWh",
        "voltage_v     214748364.7 V",
        "current_a     1.500 A",
        "frequency_hz  50.00 Hz",
    ]
