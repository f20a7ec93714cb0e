"""``pymb export --map FILE``: a map device is decoded by the given map
instead of the copy the database keeps (a corrected scale, say), and its
points can be chosen with ``--quantity``."""

from __future__ import annotations

import csv
import io
from array import array
from pathlib import Path

from conftest import run_pymb

from pymb import maps
from pymb.devices.mapreading import MapReading, group_layout, group_points
from pymb.store import DeviceInfo, Sample, SqliteSink
from pymb.store.text import CsvSink

MAP = '''schema = "pymb.map/1"
[device]
id = "tank-meter"
table = "holding"
[groups]
fast = { interval = 1 }
[[point]]
name = "level_m"
address = 0
type = "u16"
scale = %s
group = "fast"
[[point]]
name = "pump_on"
address = 1
type = "u16"
group = "fast"
'''


def _database(tmp_path: Path) -> Path:
    """Three samples of level 1234 (raw) and pump 1, logged with scale 0.01."""
    source = MAP % "0.01"
    m = maps.loads(source)
    dec = group_layout(m, "fast")[0]
    words = array("H", [1234, 1])
    b = dec.decode(words)
    names = group_points(m, "fast")
    values, states = dec.values(b), dec.states(b)
    reading = MapReading(m, "fast", {n: values[n] for n in names},
                         {n: states[n] for n in names}, words)
    db = tmp_path / "tank.sqlite"
    sink = SqliteSink(db)
    info = DeviceInfo("bus1", "127.0.0.1:502", "tank-meter", 3, "tank", map_source=source)
    for i in range(3):
        sink.write(Sample(info, 1_700_000_000.0 + i, float(i), reading))
    sink.close()
    return db


def _wide(text: str) -> list[dict[str, str]]:
    return list(csv.DictReader(io.StringIO(text)))


def test_export_decodes_by_the_stored_map_or_the_one_given(tmp_path: Path) -> None:
    db = _database(tmp_path)
    stored = run_pymb("export", str(db), "--csv", "-", "--layout", "wide")
    assert stored.returncode == 0, stored.stderr
    assert [r["level_m"] for r in _wide(stored.stdout)] == ["12.34"] * 3
    fixed = tmp_path / "tank-meter.toml"
    fixed.write_text(MAP % "0.001")  # the datasheet said millimetres after all
    given = run_pymb("export", str(db), "--csv", "-", "--layout", "wide", "--map", str(fixed))
    assert given.returncode == 0, given.stderr
    rows = _wide(given.stdout)
    assert [r["level_m"] for r in rows] == ["1.234"] * 3
    assert [r["pump_on"] for r in rows] == ["1"] * 3


def test_export_quantity_takes_a_map_point(tmp_path: Path) -> None:
    db = _database(tmp_path)
    done = run_pymb("export", str(db), "--csv", "-", "--layout", "wide",
                    "--quantity", "pump_on")
    assert done.returncode == 0, done.stderr
    rows = _wide(done.stdout)
    assert "pump_on" in rows[0]
    assert "level_m" not in rows[0]
    wrong = run_pymb("export", str(db), "--csv", "-", "--quantity", "pump_onn")
    assert wrong.returncode == 2
    assert wrong.stderr.count("\n") == 1
    assert "did you mean 'pump_on'" in wrong.stderr


def test_export_map_mistakes_are_one_line(tmp_path: Path) -> None:
    db = _database(tmp_path)
    missing = run_pymb("export", str(db), "--csv", "-", "--map", str(tmp_path / "nope.toml"))
    assert missing.returncode == 2
    assert missing.stderr.count("\n") == 1
    assert "nope.toml" in missing.stderr
    bad = tmp_path / "bad.toml"
    bad.write_text(MAP.replace('type = "u16"', 'type = "u17"', 1) % "0.01")
    broken = run_pymb("export", str(db), "--csv", "-", "--map", str(bad))
    assert broken.returncode == 2
    assert broken.stderr.count("\n") == 1
    assert "bad.toml" in broken.stderr
    assert "Traceback" not in broken.stderr


RAW_MAP = '''schema = "pymb.map/1"
[device]
id = "raw-dev"
table = "holding"
[groups]
g = { interval = 1 }
[[point]]
name = "rawregs"
address = 0
type = "raw"
count = 2
group = "g"
[[point]]
name = "level"
address = 2
type = "u16"
group = "g"
'''


def test_a_raw_point_is_one_cell_of_its_registers_in_every_csv(tmp_path: Path) -> None:
    """A ``raw`` point's registers go out as one space-separated cell with
    the point's state: in long CSV (export and the logger's sink) one row,
    in wide CSV its column."""
    m = maps.loads(RAW_MAP)
    dec = group_layout(m, "g")[0]
    words = array("H", [55125, 5306, 7])
    b = dec.decode(words)
    names = group_points(m, "g")
    values, states = dec.values(b), dec.states(b)
    reading = MapReading(m, "g", {n: values[n] for n in names},
                         {n: states[n] for n in names}, words)
    db = tmp_path / "raw.sqlite"
    sink = SqliteSink(db)
    info = DeviceInfo("bus1", "127.0.0.1:502", "raw-dev", 7, "my-dev", map_source=RAW_MAP)
    sample = Sample(info, 1_700_000_000.0, 0.0, reading)
    sink.write(sample)
    sink.close()
    logged = tmp_path / "log.csv"
    log = CsvSink(str(logged))
    log.write(sample)
    log.close()
    long = run_pymb("export", str(db), "--csv", "-", "--device", "raw-dev:7")
    assert long.returncode == 0, long.stderr
    for text in (long.stdout, logged.read_text()):
        rows = [r for r in csv.DictReader(io.StringIO(text)) if r["quantity"] == "rawregs"]
        assert [(r["channel"], r["value"], r["state"]) for r in rows] == \
            [("", "55125 5306", "value")]
    wide = run_pymb("export", str(db), "--csv", "-", "--layout", "wide")
    assert wide.returncode == 0, wide.stderr
    assert [(r["rawregs"], r["level"]) for r in _wide(wide.stdout)] == [("55125 5306", "7")]
