"""The store reads every sample back as a map reading of its map: a hub's
as the hub map's reading with its options (channels, humidity unit; a unit
per channel re-decoded; an --on-change sample's channels not stored
``not_read``; blocks the firmware lacks ``unsupported``), a CoolPro's as its
telemetry group's; ``samples_after`` turns those into the typed views
(:func:`pymb.devices.readings.reading_view`) that ``decode_hub`` and
``decode_telemetry`` give for the same registers."""

from __future__ import annotations

import math
import sqlite3
import time
from array import array
from pathlib import Path

import pytest

from pymb.devices import CoolProTelemetry, HubReading, decode_hub
from pymb.devices.coolpro import decode_telemetry
from pymb.devices.deviceconfig import shipped
from pymb.devices.mapreading import MapReading
from pymb.devices.readings import has_own_view, map_reading
from pymb.errors import InvalidArgument
from pymb.store import DeviceInfo, OnChange, Sample, SqliteSink, samples_after
from pymb.store.reader import stored_after

T0 = 1_800_000_000.0
UNITS = [0.1, 1.0, 1.0, 0.1, 1.0]  # mostly 1 %: the map decodes in 1 %, two channels again


def _sweep(seed: int) -> array[int]:
    """Registers 31..730 with values, markers of both units and offline channels."""
    words = [0xFFFF, 0x8000, 0x00FF, 0x1234, 0x0355, 0x8123, 0x00FE, 0x7FFF, 0x0001]
    return array("H", [words[(k * 7 + seed) % len(words)] for k in range(700)])


def _hub() -> DeviceInfo:
    return DeviceInfo("b", "p", "hub", 7, "hub-7", 5, tuple(UNITS))


def test_a_stored_hub_sweep_is_the_hub_maps_reading(tmp_path: Path) -> None:
    db = tmp_path / "hub.sqlite"
    written = [decode_hub(_sweep(i), UNITS, channels=5,
                          unsupported=("rssi_dbm",) if i else ()) for i in range(3)]
    sink = SqliteSink(db)
    for i, r in enumerate(written):
        sink.write(Sample(_hub(), T0 + i, float(i), r))
    sink.close()
    stored = stored_after(db, 0)
    views = samples_after(db, 0)
    assert len(stored) == len(views) == 3
    for r, s, v in zip(written, stored, views, strict=True):
        data = s.data
        assert isinstance(data, MapReading)
        assert has_own_view(data)
        assert data.map.id == "hub"
        assert data.group == "sweep"
        assert data.map.options["channels"] == 5
        assert data.map.options["humidity_unit"] == 1.0
        assert [p.channels for p in data.map.points.values()] == [5] * 7
        assert s.device.humidity_unit == tuple(UNITS)
        want = map_reading(r)
        assert dict(data.values) == dict(want.values)  # a unit per channel, as written
        assert dict(data.states) == dict(want.states)
        assert data.unsupported == want.unsupported
        assert isinstance(v.data, HubReading)
        assert v.data.as_dict() == r.as_dict()
        assert v.data.raw_states == r.raw_states
        assert v.data.registers == r.registers
        assert v.data.unsupported == r.unsupported
    assert map_reading(stored[1].data).states["rssi_dbm"] == ["unsupported"] * 5


def test_an_on_change_hub_sample_holds_only_the_channels_stored(tmp_path: Path) -> None:
    db = tmp_path / "chg.sqlite"
    first = decode_hub(_sweep(0), UNITS, channels=5)
    regs = array("H", _sweep(0))
    regs[2] = 0x0123 if regs[2] != 0x0123 else 0x0124  # channel 3's temperature moves
    second = decode_hub(regs, UNITS, channels=5)
    sink = SqliteSink(db, on_change=OnChange(heartbeat=3600))
    sink.write(Sample(_hub(), T0, 0.0, first))
    sink.write(Sample(_hub(), T0 + 1, 1.0, second))
    sink.close()
    _, s = stored_after(db, 0)
    data = s.data
    assert isinstance(data, MapReading)
    for name, states in data.states.items():
        assert [st == "not_read" for st in states] == [True, True, False, True, True], name
    temperature, humidity = data.values["temperature_c"], data.values["humidity_pct"]
    assert isinstance(temperature, list)
    assert isinstance(humidity, list)
    assert temperature[2] == second.channel(3).temperature_c
    assert humidity[2] == second.channel(3).humidity_pct
    (v,) = samples_after(db, 1)
    assert isinstance(v.data, HubReading)
    assert math.isnan(v.data.channel(1).temperature_c)
    assert v.data.channel(3).temperature_c == second.channel(3).temperature_c


def test_a_stored_coolpro_sample_is_its_telemetry_groups_reading(tmp_path: Path) -> None:
    db = tmp_path / "cp.sqlite"
    regs = array("H", [0x5FB4, 0x0CB2, 0x5DC0, 0x0C80, 41234, 4464, 1, 0x8041])
    t = decode_telemetry(regs)
    sink = SqliteSink(db)
    sink.write(Sample(DeviceInfo("b", "p", "coolpro", 40, "psu"), T0, 0.0, t))
    sink.close()
    (s,) = stored_after(db, 0)
    assert isinstance(s.data, MapReading)
    assert s.data.map.id == "coolpro"
    assert s.data.group == "telemetry"
    assert s.data.values["uptime_s"] == 70000
    assert s.data.values["status"] == 0x8041
    assert s.data.values["input_voltage_v"] == t.input_voltage_v
    (v,) = samples_after(db, 0)
    assert isinstance(v.data, CoolProTelemetry)
    assert v.data == t


def test_a_map_device_without_its_map_text_is_refused(tmp_path: Path) -> None:
    sink = SqliteSink(tmp_path / "x.sqlite")
    try:
        with pytest.raises(InvalidArgument, match="map_source"):
            sink.write(Sample(DeviceInfo("b", "p", "my-meter", 1, "m"), time.time(), 0.0,
                              decode_hub(_sweep(0))))
    finally:
        sink.close()


def test_the_hub_and_the_coolpro_keep_format_1s_layout_with_their_map_text(
        tmp_path: Path) -> None:
    """The logger hands every device's map text; the hub and the CoolPro are
    stored as format 1 had them all the same: no maps row, a hub's channels
    and their humidity units in its devices row."""
    db = tmp_path / "f1.sqlite"
    hub = DeviceInfo("b", "p", "hub", 7, "hub-7", 5, tuple(UNITS),
                     map_source=shipped("hub").text)
    cp = DeviceInfo("b", "p", "coolpro", 40, "psu", map_source=shipped("coolpro").text)
    sink = SqliteSink(db)
    sink.write(Sample(hub, T0, 0.0, decode_hub(_sweep(0), UNITS, channels=5)))
    sink.write(Sample(cp, T0, 0.0, decode_telemetry(array("H", range(8)))))
    sink.close()
    con = sqlite3.connect(db)
    try:
        assert con.execute("SELECT COUNT(*) FROM maps").fetchone() == (0,)
        assert con.execute("SELECT type, channels, humidity_units FROM devices ORDER BY id"
                           ).fetchall() == [("hub", 5, "0.1,1,1,0.1,1"), ("coolpro", 0, "")]
        assert [t for (t,) in con.execute("SELECT humidity_tenths FROM channels")] == \
            [1, 0, 0, 1, 0]
        assert [len(b) for (b,) in con.execute("SELECT registers FROM samples")] == [1400, 16]
    finally:
        con.close()
