"""docs/data.md's examples run as a user runs them, in a directory of their own,
and what they show is there: the info labels, the files, the view's state names."""

from __future__ import annotations

import re
import shlex
import shutil
import subprocess
from pathlib import Path

from conftest import run_pymb
from docblocks import NUMBER, assert_shaped, claim, claim_one

SHELL = [line[2:] for block in claim("docs/data.md", "sh", how="run")
         for line in block.lines() if line.startswith("$ ")]


def test_the_examples_run(tmp_path: Path) -> None:
    assert len(SHELL) >= 7
    outputs = []
    for line in SHELL:
        argv = shlex.split(line)
        if argv[0] == "pymb":
            done = run_pymb(*argv[1:], cwd=tmp_path, timeout=120)
        else:
            tool = shutil.which(argv[0])
            assert tool, argv[0]
            done = subprocess.run([tool, *argv[1:]], cwd=tmp_path, capture_output=True,
                                  text=True, timeout=60, check=False)
        assert done.returncode == 0, (line, done.stdout, done.stderr)
        assert "Traceback" not in done.stderr
        outputs.append(done.stdout)
    info = outputs[1]
    shown = claim_one("docs/data.md", "text", how="compare")
    labels = [ln.split()[0] for ln in shown.lines()[1:] if ln.startswith("  ") and
              not ln.startswith("    ")]
    assert labels == ["writer", "time", "samples", "devices", "faults", "events", "size",
                      "forwarder"]
    # line by line as pymb info prints it; the demo's faults are random, so
    # that line is checked for its form only
    real = info.splitlines()
    (faults,) = [ln for ln in real if ln.startswith("  faults ")]
    assert re.fullmatch(rf"  faults\s+(none|{NUMBER}: {NUMBER} \w+(, {NUMBER} \w+)*)", faults)
    assert_shaped(shown, [shown.lines()[real.index(ln)] if ln is faults else ln for ln in real])
    for name in ("t2.png", "vout.svg", "wide.csv", "vout.csv"):
        assert (tmp_path / name).stat().st_size > 0, name
    left = {p.name for p in tmp_path.iterdir()}  # the readers left no -wal or -shm
    assert {"demo.sqlite", "t2.png", "vout.svg", "wide.csv", "vout.csv"} <= left
    assert not [n for n in left if n.endswith(("-wal", "-shm", ".tmp"))], left
    assert (tmp_path / "wide.csv").read_text().splitlines()[0].endswith(
        "temperature_c_1,humidity_pct_1,temperature_c_2,humidity_pct_2,temperature_c_3,"
        "humidity_pct_3")
    rows = [r.split("|") for r in outputs[-1].splitlines()]
    assert len(rows) == 6
    assert all(r[0].endswith("Z") and "T" in r[0] for r in rows)
    assert {r[3] for r in rows} <= {"value", "offline", "no_sensor"}
