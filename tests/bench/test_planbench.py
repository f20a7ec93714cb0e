"""The bench's plan section: what it plans is a real plan of the synthetic
map, and the report shows it (the figure itself is the bench's, not a test's)."""

from __future__ import annotations

from pymb.bench import planbench, report
from pymb.bench.table import fmt_time
from pymb.maps.planner import Line, plan_points


def test_plan_section_reports_the_plan_of_the_synthetic_map() -> None:
    said: list[str] = []
    section = planbench.run_section(1, said.append)
    assert said == ["plan: 1000-point map"]
    items = planbench.synthetic_points()
    assert len(items) == 1000
    assert {it.table for it in items} == {"holding", "input"}
    assert section["points"] == 1000
    assert section["plan_ms"] > 0
    # the same map planned without bridges costs at least as much: the
    # section's plan is the bridged optimum, cheaper than the naive one
    plain = plan_points(items, Line(9600, 10, 0.005, 0.002))
    assert plain.predicted_s * 1e3 >= section["predicted_ms"]
    assert section["predicted_ms"] <= plain.predicted_s * 1e3 + 1e-9
    assert section["predicted_ms"] < section["naive_ms"]
    what, goal, measured, unit, met = planbench.targets(section)[0]
    assert (what, goal, unit) == ("planning a 1000-point map", "<= 100 ms", "us")
    assert measured == section["plan_ms"] * 1e3
    assert met == (section["plan_ms"] <= 100)
    result = {"meta": {"plan": {}, "quick": False}, "contenders": [], "plan": section,
              "targets": []}
    table = next(t for t in report.tables(result) if t.title.startswith("Planning"))
    assert table.title == "Planning: the reads of a 1000-point map"
    assert table.rows[0][:4] == ["1000", fmt_time(section["plan_ms"] * 1e3),
                                 str(section["requests"]), str(section["registers"])]
