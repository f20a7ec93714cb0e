"""The README's examples run: its Python example against simulated devices
on a pseudo-terminal in place of /dev/ttyUSB0, its C example compiled
against csrc/ and run the same way; and the README stays a front door."""

from __future__ import annotations

import contextlib
import io
import re
import shutil
import subprocess
from pathlib import Path

import pytest
from docblocks import claim_one

from pymb.devices import State
from pymb.sim import Simulator

ROOT = Path(__file__).resolve().parents[2]
README = (ROOT / "README.md").read_text()


def block(lang: str) -> str:
    if lang == "python":
        return claim_one("README.md", "python", how="run").text
    return claim_one("README.md", "c", how="compile").text


def test_the_readme_is_a_front_door() -> None:
    assert len(README.splitlines()) <= 300
    for link in re.findall(r"\]\(((?:docs/|CHANGELOG)[^)#]*)", README):
        assert (ROOT / link).exists(), link


def test_the_python_example_runs() -> None:
    code = block("python")
    assert len(code.splitlines()) <= 12
    with Simulator(["coolpro", "hub:1"], seed=5) as sim:
        out = io.StringIO()
        with contextlib.redirect_stdout(out):
            exec(compile(code.replace("/dev/ttyUSB0", sim.port), "README.md", "exec"), {})
    first, second = out.getvalue().splitlines()
    assert len(first.split()) == 4
    assert second.split()[1] in State.__members__


@pytest.mark.skipif(shutil.which("make") is None or shutil.which("cc") is None,
                    reason="needs make and a C compiler")
def test_the_c_example_builds_and_runs(tmp_path: Path) -> None:
    subprocess.run(["make", "-s", "-C", str(ROOT / "csrc"), f"B={tmp_path}", "lib"],
                   check=True, capture_output=True, timeout=600)
    with Simulator(["coolpro"], seed=5) as sim:
        (tmp_path / "app.c").write_text(block("c").replace("/dev/ttyUSB0", sim.port))
        flags = subprocess.run(["pkg-config", "--cflags", "--libs", "libmodbus"], check=True,
                               capture_output=True, text=True).stdout.split()
        subprocess.run(["cc", "-std=c99", "-Wall", "-Werror", "-o", str(tmp_path / "app"),
                        str(tmp_path / "app.c"), f"-I{ROOT / 'csrc'}",
                        str(tmp_path / "libpymb.a"), *flags, "-lm"],
                       check=True, capture_output=True, timeout=120)
        run = subprocess.run([str(tmp_path / "app")], capture_output=True, text=True,
                             timeout=60, check=False)
    assert run.returncode == 0, run.stderr
    assert re.fullmatch(r"input voltage \d+\.\d{3} V\n", run.stdout), run.stdout
