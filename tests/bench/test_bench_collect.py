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
    assert 0 <= s["lag"]["lag_p50_s"] <= s["lag"]["lag_p99_s"]
    assert s["scaling"] > 0
    md = report.to_markdown(result)
    assert "Collect: 100 boards' SDM630 samples" in md
    assert "lag (postgresql" in md
