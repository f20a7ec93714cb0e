"""The bench's ``maps`` section races the hub and the CoolPro through their
maps against the dedicated facades over the sweep section's simulator, and
reports the pairs, their ratios and the target row. No timing assertions:
the figures are the bench's."""

from __future__ import annotations

import json
import math
from typing import Any

import pytest

from pymb.bench import mapwire, report, runner
from pymb.bench.table import fmt_x
from pymb.cli import main


def test_quick_maps_section_reports_both_pairs_side_by_side(
        capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "--quick", "-q", "--json", "--sections", "maps",
                 "--only", "pymb"]) == 0
    result: dict[str, Any] = json.loads(capsys.readouterr().out)
    wire = result["maps"]["wire"]
    rounds = 3 * mapwire.ROUNDS_PER_ROUND  # --quick: 3 rounds of the sweep comparison
    assert wire["rounds"] == rounds
    assert wire["baud"] == 115200
    for key, _ in mapwire.PAIRS:
        pair = wire[key]
        for side in ("map", "dedicated"):
            assert pair[f"{side}_cpu_us"] > 0
            assert pair[f"{side}_wall_us"] > 0
        assert len(pair["round_cpu_x"]) == rounds
        assert pair["cpu_x"] == pytest.approx(sorted(pair["round_cpu_x"])[rounds // 2])
        assert math.isfinite(pair["wall_x"])
        assert pair["wall_x"] > 0
    # --quick judges no target; a full run puts the pair in the targets table
    assert result["targets"] == []
    rows = [t for t in runner.targets(result) if "through its map, CPU per read" in t["what"]]
    assert len(rows) == 1
    assert rows[0]["target"] == "<= 1.00x"
    assert rows[0]["measured"] == wire["hub"]["cpu_x"]
    table = next(t for t in report.tables(result) if t.title.startswith(
        "Maps over the wire: MapDevice against the dedicated facade"))
    assert [r[0] for r in table.rows] == [what for _, what in mapwire.PAIRS]
    assert table.rows[0][3] == fmt_x(wire["hub"]["cpu_x"])
    assert "Maps over the wire" in report.to_text(result)
    assert "Maps over the wire" in report.to_markdown(result)
