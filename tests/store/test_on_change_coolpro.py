"""Report by exception for a CoolPro (``--on-change``): a sample is stored
when a quantity moved past its deadband since the last stored sample, when
the status changes, when the device restarted (its uptime went back), and at
least every heartbeat; otherwise never. What was stored is read back from the
database, not from the rules' own state."""

from __future__ import annotations

import sqlite3
from array import array
from pathlib import Path

from pymb.devices import CoolProStatus, CoolProTelemetry
from pymb.store import DeviceInfo, OnChange, Sample, SqliteSink

T0 = 1_800_000_000.0
PSU = DeviceInfo("b", "p", "coolpro", 40, "psu")


def telemetry(uptime: int, temperature_mc: int = 30_000, status: int = 0,
              vin_mv: int = 24_000) -> CoolProTelemetry:
    """Telemetry as the device sends it (input registers 0..7, milliunits,
    uptime low word first) and as the facade decodes it."""
    regs = array("H", [vin_mv, 500, 12_000, 1_000, temperature_mc, uptime & 0xFFFF,
                       uptime >> 16, status])
    return CoolProTelemetry(vin_mv / 1000, 0.5, 12.0, 1.0, temperature_mc / 1000, uptime,
                            CoolProStatus(status), regs)


def stored_uptimes(db: Path, steps: list[tuple[float, CoolProTelemetry]],
                   rules: OnChange) -> list[int]:
    sink = SqliteSink(db, on_change=rules)
    for mono, data in steps:
        sink.write(Sample(PSU, T0 + mono, mono, data))
    sink.close()
    with sqlite3.connect(db) as con:
        return [u for (u,) in con.execute("SELECT uptime_s FROM coolpro_readings ORDER BY "
                                          "sample_id")]


def test_a_steady_device_is_stored_once_until_its_heartbeat(tmp_path: Path) -> None:
    steps = [(float(t), telemetry(1000 + t)) for t in range(30)]  # only the uptime moves
    steps.append((61.0, telemetry(1061)))
    assert stored_uptimes(tmp_path / "a.sqlite", steps, OnChange(60.0)) == [1000, 1061]


def test_a_move_past_the_deadband_is_stored_and_one_within_it_is_not(tmp_path: Path) -> None:
    steps = [
        (0.0, telemetry(100, 30_000)),
        (1.0, telemetry(101, 30_300)),  # +0.3 °C: within 0.5
        (2.0, telemetry(102, 30_450)),  # +0.45 °C since the stored one: within
        (3.0, telemetry(103, 30_600)),  # +0.6 °C since the stored one: stored
        (4.0, telemetry(104, 30_200)),  # -0.4 °C: within
        (5.0, telemetry(105, 30_200, vin_mv=24_001)),  # any change of a quantity without a band
    ]
    got = stored_uptimes(tmp_path / "b.sqlite", steps, OnChange(60.0, {"temperature_c": 0.5}))
    assert got == [100, 103, 105]


def test_a_restart_is_stored_though_nothing_else_changed(tmp_path: Path) -> None:
    steps = [
        (0.0, telemetry(5000)),
        (1.0, telemetry(5001)),
        (2.0, telemetry(3)),    # the uptime went back: the device restarted
        (3.0, telemetry(4)),
    ]
    assert stored_uptimes(tmp_path / "c.sqlite", steps, OnChange(60.0)) == [5000, 3]


def test_a_status_change_is_stored(tmp_path: Path) -> None:
    steps = [(0.0, telemetry(10)), (1.0, telemetry(11, status=0x0001)),
             (2.0, telemetry(12, status=0x0001)), (3.0, telemetry(13))]
    assert stored_uptimes(tmp_path / "d.sqlite", steps, OnChange(60.0)) == [10, 11, 13]
