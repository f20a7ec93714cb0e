"""docs/map-devices.md's examples run: its TOML block is the map every
Python block uses (``DEMO``), and each ``$ pymb`` line of its shell block runs
as a user would run it against the ``pymb simulate`` line's simulator."""

from __future__ import annotations

import shlex
from pathlib import Path

import pytest
from conftest import run_pymb
from docblocks import claim, claim_one

from pymb.sim import SimulatorProcess

DEMO = claim_one("docs/map-devices.md", "toml", how="load").text
BLOCKS = [b.text for b in claim("docs/map-devices.md", "python", how="run")]
SHELL = [line[2:] for block in claim("docs/map-devices.md", "sh", how="run")
         for line in block.lines() if line.startswith("$ pymb ")]


@pytest.mark.parametrize("code", BLOCKS, ids=[f"block{i}" for i in range(len(BLOCKS))])
def test_python_examples_run(code: str) -> None:
    assert len(BLOCKS) >= 2
    exec(compile(code, "docs/map-devices.md", "exec"), {"DEMO": DEMO})


def test_shell_examples_run(tmp_path: Path) -> None:
    (tmp_path / "meter.toml").write_text(DEMO)
    simulate = next(line for line in SHELL if line.startswith("pymb simulate"))
    doc_endpoint = simulate.split("--tcp ")[1].split()[0]
    args = shlex.split(simulate)[2:]
    args[args.index("--tcp") + 1] = "127.0.0.1:0"  # a free port, not the doc's
    args[args.index("meter.toml")] = str(tmp_path / "meter.toml")
    others = [line for line in SHELL if line is not simulate]
    assert len(others) >= 6
    with SimulatorProcess(args, quiet=True) as sim:
        for line in others:
            argv = shlex.split(line.replace(doc_endpoint, sim.endpoint))[1:]
            r = run_pymb(*argv, cwd=tmp_path)
            assert r.returncode == 0, (line, r.stdout, r.stderr)
            assert r.stdout.strip(), line
    check = run_pymb("map", "check", "meter.toml", cwd=tmp_path)
    assert "input registers 0..7 (8)" in check.stdout
