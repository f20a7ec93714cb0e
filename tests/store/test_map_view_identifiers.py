"""A map's views are SQL generated from its names: a point named as an SQL
keyword (``index``, ``order``, ``group``) and a map id that starts with a
digit are valid map names, so the views quote them; logging such a map
works and its view reads back the values."""

from __future__ import annotations

import sqlite3
from pathlib import Path

from conftest import run_pymb

from pymb.sim import SimulatorProcess

MAP = '''schema = "pymb.map/1"
[device]
id = "3ph-meter"
table = "holding"
[[point]]
name = "index"
address = 0
type = "u16"
example = 3
[[point]]
name = "order"
address = 1
type = "u16"
example = 4
[[block]]
name = "group"
first = 2
count = 2
type = "u16"
example = 5
'''


def test_keywords_and_a_leading_digit_log_and_read_back(tmp_path: Path) -> None:
    f, db = tmp_path / "m.toml", tmp_path / "k.sqlite"
    f.write_text(MAP)
    with SimulatorProcess(["--map", str(f), "3ph-meter:7", "--tcp", "127.0.0.1:0"],
                          quiet=True) as sim:
        r = run_pymb("log", "--map", str(f), "3ph-meter:7", "--tcp", sim.endpoint,
                     "--seconds", "1", "--interval", "0.2", "--out", str(db), "--quiet")
    assert r.returncode == 0, r.stderr
    con = sqlite3.connect(db)
    try:
        rows = con.execute('SELECT "index", "order" FROM "3ph_meter_readings"').fetchall()
        channels = con.execute('SELECT channel, "group" FROM "3ph_meter_channels" '
                               "WHERE sample_id = (SELECT min(id) FROM samples) "
                               "ORDER BY channel").fetchall()
    finally:
        con.close()
    assert rows
    assert set(rows) == {(3, 4)}
    assert channels == [(1, 5), (2, 5)]
