"""A map device polled by groups is one device wherever devices are listed:
``pymb info`` (text and JSON, with its samples per group), ``export
--device`` (its ``TYPE:ADDRESS`` found, the "it has" list), and the
forwarder's device list (one birth each). The database is written by
``pymb log`` from ``pymb simulate`` over TCP; the figures are checked
against SQL of the test's own."""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import pytest
from conftest import run_pymb

from pymb.sim import SimulatorProcess
from pymb.store import Outbox


@pytest.fixture(scope="module")
def grouped(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two shipped meters logged by groups (fast, energy, config; the
    SDM630 with quality too): a devices row per group."""
    db = tmp_path_factory.mktemp("info") / "groups.sqlite"
    with SimulatorProcess(["eastron-sdm120:1", "eastron-sdm630:2", "--tcp", "127.0.0.1:0"],
                          quiet=True) as sim:
        r = run_pymb("log", "--tcp", sim.endpoint, "eastron-sdm120:1", "eastron-sdm630:2",
                     "--seconds", "1.5", "--out", str(db), "--quiet")
    assert r.returncode == 0, r.stderr
    return db


def _by_group(db: Path) -> dict[str, dict[str, int]]:
    con = sqlite3.connect(db)
    try:
        got: dict[str, dict[str, int]] = {}
        for name, units, n in con.execute(
                "SELECT d.name, d.humidity_units, COUNT(s.id) FROM devices d "
                "LEFT JOIN samples s ON s.device_id = d.id GROUP BY d.id ORDER BY d.id"):
            got.setdefault(name, {})[units.split(",")[0].removeprefix("group=")] = n
        return got
    finally:
        con.close()


def test_info_lists_a_map_device_once_with_its_groups(grouped: Path) -> None:
    want = _by_group(grouped)
    assert len(want["eastron-sdm120-1"]) == 3  # fast, energy, config: three rows
    assert len(want["eastron-sdm630-2"]) == 4  # and quality
    r = run_pymb("info", str(grouped), "--json")
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    assert [d["name"] for d in doc["devices"]] == ["eastron-sdm120-1", "eastron-sdm630-2"]
    for d in doc["devices"]:
        assert d["groups"] == want[d["name"]]
        assert d["samples"] == sum(want[d["name"]].values())
    assert doc["samples"] == sum(sum(g.values()) for g in want.values())
    text = run_pymb("info", str(grouped)).stdout
    assert "  devices     2\n" in text
    assert text.count("eastron-sdm120-1 ") == 1, text
    g = want["eastron-sdm120-1"]
    assert (f"eastron-sdm120:1 on bus1 ({doc['devices'][0]['port']}): {sum(g.values())} "
            f"samples ({g['fast']} fast, {g['energy']} energy, {g['config']} config), ") in text


def test_export_finds_a_map_device_by_type_and_address(grouped: Path) -> None:
    r = run_pymb("export", str(grouped), "--csv", "-", "--device", "eastron-sdm120:1",
                 "--layout", "wide")
    assert r.returncode == 0, r.stderr
    rows = r.stdout.strip().splitlines()[1:]
    assert len(rows) == sum(_by_group(grouped)["eastron-sdm120-1"].values())
    assert all(",eastron-sdm120-1,eastron-sdm120,1," in row for row in rows)
    r = run_pymb("export", str(grouped), "--csv", "-", "--device", "eastron-sdm120:7")
    assert r.returncode == 2, r.stderr
    assert r.stderr.strip().endswith(
        "it has: eastron-sdm120-1 (eastron-sdm120:1 on bus1), "
        "eastron-sdm630-2 (eastron-sdm630:2 on bus1)"), r.stderr


def test_the_forwarders_device_list_has_each_device_once(grouped: Path) -> None:
    outbox = Outbox(str(grouped))
    try:
        assert outbox.devices() == [("eastron-sdm120-1", "eastron-sdm120", 1),
                                    ("eastron-sdm630-2", "eastron-sdm630", 2)]
    finally:
        outbox.close()
