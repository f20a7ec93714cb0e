"""``pymb bench --sections collect --quick``: every value of 100 boards' samples
stored through a real mosquitto into SQLite and a real PostgreSQL, by one and
by two collectors, with figures and a lag; the report shows them."""

from __future__ import annotations

import json

import pytest

from pymb.bench import report
from pymb.cli import main


def test_collect_section(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "--quick", "--only", "pymb", "--sections", "collect",
                 "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    s = result["collect"]
    assert s["status"] == "ok", s
    assert s["boards"] == 100
    assert s["points"] == 74  # the SDM630 map's readable points
    assert [(r["target"], r["collectors"]) for r in s["rows"]] == [
        ("sqlite", 1), ("postgresql", 1), ("postgresql", 2)]
    for r in s["rows"]:
        # the section waits for every value in the database: all stored, once
        assert r["values"] == 100 * s["samples"] * 74
        assert r["values_per_s"] > 0
        assert r["values_per_cpu_s"] > 0
        # CPU per value of each part (the database's own processes for PostgreSQL;
        # SQLite runs in the collector), and the machine's busy cores
        us = r["cpu_us_per_value"]
        assert us["collectors"] > 0
        assert (us["database"] > 0) == (r["target"] == "postgresql")
        assert 0 < r["ours_cores"] <= r["busy_cores"] * 1.2 + 0.1
        assert r["busy_cores"] <= s["cpus"] + 0.1
    for lag in (s["lag"], s["fleet_lag"]):
        assert 0 <= lag["lag_p50_s"] <= lag["lag_p99_s"]
    assert s["lag"]["values_per_s"] == pytest.approx(100_000)
    assert s["fleet_lag"]["values_per_s"] == pytest.approx(100 * 74)
    assert s["scaling"] > 0
    md = report.to_markdown(result)
    assert "Collect: 100 boards' SDM630 samples" in md
    assert "lag (postgresql" in md
    assert "lag of a fleet of 100 boards" in md
    assert "cores busy (ours)" in md
