"""docs/maps.md's examples run: its first TOML block is the map (``DEMO``)
every Python block below it uses."""

from __future__ import annotations

import pytest
from docblocks import claim, claim_one

from pymb import maps

DEMO = claim_one("docs/maps.md", "toml", how="load").text
BLOCKS = [b.text for b in claim("docs/maps.md", "python", how="run")]


def test_the_demo_map_loads() -> None:
    m = maps.loads(DEMO, source="demo.toml")
    assert list(m.points) == ["voltage_v", "energy_wh", "setpoint_hz", "mode", "temperature_c"]


@pytest.mark.parametrize("code", BLOCKS, ids=[f"block{i}" for i in range(len(BLOCKS))])
def test_python_examples_run(code: str) -> None:
    assert BLOCKS, "docs/maps.md has Python examples"
    exec(compile(code, "docs/maps.md", "exec"), {"DEMO": DEMO})
