"""The compact text of a reading, a rule over its map's data: a CoolPro's
status bits as the view always named them (none set: ``ok``; bits the map
does not declare: ``reserved bits``), and any map whose points form an
indexed array (blocks of as many channels) as one table, a row a channel
and a column a quantity, as the hub's."""

from __future__ import annotations

from array import array

from pymb import maps
from pymb.commands._common import render, to_json
from pymb.commands.maptext import indexed, labelled_text, table_text
from pymb.devices.coolpro import decode_telemetry
from pymb.devices.readings import map_reading

BLOCKS = '''schema = "pymb.map/1"
[device]
id = "tanks"
[[block]]
name = "level_m"
first = 0
count = 3
stride = 1
type = "u16"
scale = 0.01
unit = "m"
markers = { 0xFFFF = "offline" }
[[block]]
name = "flow_lpm"
first = 10
count = 3
stride = 1
type = "i16"
unit = "l/min"
[[point]]
name = "alarm"
address = 20
type = "u16"
'''


def _status_line(status: int) -> str:
    regs = array("H", [24500, 3250, 24000, 3200, 31500, 70000 & 0xFFFF, 70000 >> 16, status])
    last = render(map_reading(decode_telemetry(regs))).splitlines()[-1]
    label = "Status Flags bit field; bits 7..15 reserved "  # (the map's description)
    assert last.startswith(label)
    return last[len(label):]


def test_coolpro_status_bits() -> None:
    assert _status_line(0x0000) == "0x0000 (ok)"
    assert _status_line(0x0041) == "0x0041 (SYSTEM_STARTUP, TEMPERATURE_SENSOR_FAULT)"
    assert _status_line(0x8044) == ("0x8044 (INPUT_MEASUREMENT_FAULT, TEMPERATURE_SENSOR_FAULT)"
                                    " reserved bits 0x8000")
    assert _status_line(0x0100) == "0x0100 (ok) reserved bits 0x0100"


def test_coolpro_lines_and_json() -> None:
    regs = array("H", [24500, 3250, 24000, 3200, 31500, 70000 & 0xFFFF, 70000 >> 16, 0])
    r = map_reading(decode_telemetry(regs))
    assert render(r).splitlines()[:6] == [
        "Input Voltage    24.500 V", "Input Current    3.250 A", "Output Voltage   24.000 V",
        "Output Current   3.200 A", "Temperature      31.500 °C", "Uptime           70000 s"]
    assert to_json(r) == {"input_voltage_v": 24.5, "input_current_a": 3.25,
                          "output_voltage_v": 24.0, "output_current_a": 3.2,
                          "temperature_c": 31.5, "uptime_s": 70000, "status": 0,
                          "status_flags": []}


def test_any_maps_indexed_array_is_a_table() -> None:
    m = maps.loads(BLOCKS, source="tanks.toml")
    assert indexed(m, ["level_m", "flow_lpm"])
    assert not indexed(m, ["level_m", "alarm"])
    assert not indexed(maps.builtin("coolpro"), ["input_voltage_v"])
    values = {"level_m": [1.25, None, 0.5], "flow_lpm": [-3, 12, 0]}
    states = {"level_m": ["value", "offline", "value"], "flow_lpm": ["value"] * 3}
    assert table_text(m, values, states).splitlines() == [
        "ch  level [m]  flow [l/min]",
        " 1       1.25            -3",
        " 2    offline            12",
        " 3        0.5             0",
    ]
    assert table_text(m, values, states, ["flow_lpm"]).splitlines()[-1] == \
        "not supported by this firmware: flow_lpm"
    assert labelled_text(m, {"alarm": 3}, {"alarm": "value"}) == "alarm            3"


ENERGY = '''schema = "pymb.map/1"
[device]
id = "meter"
[[point]]
name = "energy_kwh"
address = 0
type = "f32"
unit = "kWh"
description = "Import energy"
[[point]]
name = "voltage_v"
address = 2
type = "u16"
scale = 0.1
unit = "V"
description = "Voltage"
'''


def test_a_line_a_point_shows_the_digits_a_number_has() -> None:
    # the rule number_text keeps for every map point: an f32's shortest digits
    # (123456.7, not 6 significant digits' 123457), a scale's decimals
    m = maps.loads(ENERGY, source="meter.toml")
    text = labelled_text(m, {"energy_kwh": 123456.703125, "voltage_v": 230.0},
                         {"energy_kwh": "value", "voltage_v": "value"})
    assert text.splitlines() == ["Import energy    123456.7 kWh", "Voltage          230.0 V"]
