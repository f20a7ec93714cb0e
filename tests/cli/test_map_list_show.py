"""``pymb map list`` (the shipped maps: id, title, ref) and ``pymb map show
ID`` (a map's points as a table), run as a user runs them."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest
from conftest import run_pymb

from pymb import maps
from pymb.commands.mapshow import run_show

MAP = '''schema = "pymb.map/1"
[device]
id = "inv"
manufacturer = "ACME"
model = "PV-5"
ref = "ACME PV-5 map rev 3"
address_base = 1
[[point]]
name = "W"
address = 40084
type = "i16"
scale_from = "W_SF"
unit = "W"
[[point]]
name = "W_SF"
address = 40085
type = "sunssf"
[[point]]
name = "limit_pct"
address = 40100
type = "u16"
scale = 0.1
offset = -5
unit = "%"
access = "rw"
valid = [0, 100]
[[point]]
name = "state"
address = 40100
type = "u16"
mask = 0x6F
[[block]]
name = "string_v"
first = 40200
count = 3
stride = 2
type = "u16"
'''


def test_list_names_every_shipped_map_with_its_title_and_source() -> None:
    r = run_pymb("map", "list")
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert lines[0].split() == ["id", "title", "ref"]
    ids = [line.split()[0] for line in lines[1:]]
    assert ids == sorted(maps.builtin_ids())
    sdm = next(line for line in lines if line.startswith("eastron-sdm120 "))
    assert "Eastron SDM120-Modbus" in sdm
    assert sdm.rstrip().endswith(maps.builtin("eastron-sdm120").device.ref)
    j = run_pymb("map", "list", "--json")
    assert j.returncode == 0, j.stderr
    rows = json.loads(j.stdout)
    assert [r["id"] for r in rows] == ids
    assert all(r["ref"] == maps.builtin(r["id"]).device.ref for r in rows)


def test_show_prints_each_point_of_a_map_file(tmp_path: Path) -> None:
    path = tmp_path / "inv.toml"
    path.write_text(MAP)
    r = run_pymb("map", "show", str(path))
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert lines[0] == "inv: ACME PV-5 (ACME PV-5 map rev 3), 5 points"
    assert lines[1].split() == ["name", "address", "table", "type", "scale/unit", "access",
                                "valid"]
    rows = {line.split()[0]: line for line in lines[2:]}
    assert list(rows) == ["W", "W_SF", "limit_pct", "state", "string_v"]
    assert rows["W"].split() == ["W", "40084", "holding", "i16", "x10^W_SF", "W", "r", "-"]
    assert rows["limit_pct"].split() == ["limit_pct", "40100", "holding", "u16", "x0.1", "-5",
                                         "%", "rw", "0..100"]
    assert "u16 & 0x6F" in rows["state"]
    assert "40200 (+2 x 3)" in rows["string_v"]
    j = json.loads(run_pymb("map", "show", str(path), "--json").stdout)
    assert j["id"] == "inv"
    assert j["points"][2] == {"name": "limit_pct", "address": "40100", "table": "holding",
                              "type": "u16", "scale": "x0.1 -5 %", "access": "rw",
                              "valid": [0, 100]}


def test_show_a_shipped_map_and_an_unknown_one() -> None:
    r = run_pymb("map", "show", "eastron-sdm120")
    assert r.returncode == 0, r.stderr
    m = maps.builtin("eastron-sdm120")
    assert len(r.stdout.splitlines()) == 2 + len(m.points)
    assert "voltage_v" in r.stdout
    bad = run_pymb("map", "show", "eastron-sdm12")
    assert bad.returncode == 2
    assert bad.stderr.count("\n") == 1
    assert "did you mean 'eastron-sdm120'" in bad.stderr
    assert "Traceback" not in bad.stderr


def test_show_renders_every_shipped_map(capsys: pytest.CaptureFixture[str]) -> None:
    for ident in maps.builtin_ids():
        assert run_show(argparse.Namespace(map=ident, json=False)) == 0
        out = capsys.readouterr().out.splitlines()
        m = maps.builtin(ident)
        assert out[0].startswith(f"{ident}: ")
        assert [line.split()[0] for line in out[2:]] == list(m.points)
