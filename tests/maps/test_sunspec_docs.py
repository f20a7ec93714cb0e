"""docs/sunspec.md's examples run: its commands against a SunSpec device that
is not pymb (pysunspec2's registers served by pymodbus) standing in for
192.168.1.60:502, the probe's output as the page shows it, its Python."""

from __future__ import annotations

import json
import re
import shlex
from pathlib import Path
from typing import Any

from conftest import run_pymb
from docblocks import assert_shaped, claim_one
from sunspec_peer import image, serve

from pymb.devices.mapreading import MapReading
from pymb.store import samples_after

DEVICE: list[tuple[int, dict[str, Any]]] = [
    (1, {"Mn": "Acme Solar", "Md": "AS-10K", "SN": "SN0042"}),
    (103, {"W": 3342, "W_SF": 0, "PhVphA": 2301, "V_SF": -1, "St": 4}),
    (160, {"DCA_SF": -2, "N": 3, "module": [{"ID": 1, "DCA": 812}, {"ID": 2}, {"ID": 3}]}),
]


def test_the_commands_run_and_the_probe_prints_what_the_page_shows(tmp_path: Path) -> None:
    block = claim_one("docs/sunspec.md", "sh", how="run")
    shown = claim_one("docs/sunspec.md", "text", how="compare")
    regs = image(DEVICE)
    regs = [*regs[:-2], 64999, 4, 0, 0, 0, 0, *regs[-2:]]
    lines = [shlex.split(line, comments=True) for line in block.lines() if line.strip()]
    assert [a[:2] for a in lines] == [["pymb", "map"], ["pymb", "read"], ["pymb", "read"],
                                      ["pymb", "log"], ["pymb", "map"]]
    with serve(regs, tmp_path) as server:
        outputs = []
        for argv in lines:
            args = [f"127.0.0.1:{server.port}" if a == "192.168.1.60:502" else a
                    for a in argv[1:]]
            if args[0] == "log":
                args += ["--seconds", "2", "--quiet"]
            done = run_pymb(*args, cwd=tmp_path)
            assert done.returncode == 0, (argv, done.stderr)
            assert "Traceback" not in done.stderr
            outputs.append(done.stdout)
    assert_shaped(shown, outputs[0].splitlines())
    assert re.search(r"^inverter_three_phase\.W +3342(\.0)? W$", outputs[1], re.M), outputs[1]
    assert json.loads(outputs[2])["values"]["mppt.module.DCA"] == [8.12, None, None]
    stored = [s.data.values for s in samples_after(tmp_path / "solar.sqlite", 0, limit=100)
              if isinstance(s.data, MapReading)]
    assert any(v.get("inverter_three_phase.W") == 3342 for v in stored)
    saved = (tmp_path / "inverter.toml").read_text()
    assert 'id = "sunspec-1-103-160"' in saved


def test_the_python_example_runs() -> None:
    code = claim_one("docs/sunspec.md", "python", how="run").text
    exec(compile(code, "docs/sunspec.md", "exec"), {})
