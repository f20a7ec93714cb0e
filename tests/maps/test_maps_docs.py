"""docs/maps.md's examples run: its first TOML block is the map (``DEMO``)
every Python block below it uses."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from pymb import maps

DOC = (Path(__file__).resolve().parents[2] / "docs" / "maps.md").read_text()
DEMO = re.findall(r"```toml\n(.*?)```", DOC, re.S)[0]
BLOCKS = re.findall(r"```python\n(.*?)```", DOC, re.S)


def test_the_demo_map_loads() -> None:
    m = maps.loads(DEMO, source="demo.toml")
    assert list(m.points) == ["voltage_v", "energy_wh", "setpoint_hz", "mode", "temperature_c"]


@pytest.mark.parametrize("code", BLOCKS, ids=[f"block{i}" for i in range(len(BLOCKS))])
def test_python_examples_run(code: str) -> None:
    assert BLOCKS, "docs/maps.md has Python examples"
    exec(compile(code, "docs/maps.md", "exec"), {"DEMO": DEMO})
