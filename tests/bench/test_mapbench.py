"""The bench's maps section decodes what the reference decodes, and the
report shows its figures (the figures themselves are the bench's)."""

from __future__ import annotations

import struct

from pymb import maps
from pymb.bench import mapbench, report
from pymb.bench.table import fmt_time


def test_maps_section_reports_the_one_call_decode() -> None:
    said: list[str] = []
    section = mapbench.run_section(3, said.append)
    assert said == ["maps: 100-point f32 map"]
    m = maps.loads(mapbench.map_text(), source="bench.toml")
    assert len(m.points) == 100
    assert {p.type for p in m.points.values()} == {"f32"}
    regs = mapbench.registers()
    values = maps.Decoder(m).read(regs)
    assert values["v7"] == struct.unpack(">f", struct.pack(">2H", regs[14], regs[15]))[0]
    assert 0 < section["decode_us"] < section["read_us"] < section["python_us"]
    assert section["hub_map_us"] > 0
    what, goal, measured, unit, met = mapbench.targets(section)[0]
    assert (goal, unit) == ("<= 10 us", "us")
    assert "100-point f32 map in one C call" in what
    assert met == (measured <= 10)
    result = {"meta": {"plan": {}, "quick": False}, "contenders": [], "maps": section,
              "targets": []}
    table = next(t for t in report.tables(result) if t.title.startswith("Maps"))
    assert table.rows[0][:2] == ["100", fmt_time(section["decode_us"])]
