"""``pymb plot`` of what it cannot draw, as a user runs it: a text point of a
map device, and a point the device never gave a value (it refuses it),
each said in one line with a non-zero exit and no image written (no empty
chart with a 1970 axis). And the install hint when matplotlib is missing is
a command that runs."""

from __future__ import annotations

import shlex
import subprocess
import sys
from pathlib import Path

import pytest
from clikit import no_traceback
from conftest import PYMB_ENV, run_pymb

from pymb.sim import SimulatorProcess

SERVED = '''schema = "pymb.map/1"
[device]
id = "plot-meter"
table = "input"
[[point]]
name = "voltage_v"
address = 0
type = "f32"
unit = "V"
example = 230.5
[[point]]
name = "model_name"
table = "holding"
address = 0
type = "string"
count = 4
example = "M-1"
'''

#: the logger's map: one point more than the device has (it answers exception 02)
LOGGED = SERVED + '''[[point]]
name = "missing_a"
address = 100
type = "f32"
unit = "A"
'''


@pytest.fixture(scope="module")
def logged(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    where = tmp_path_factory.mktemp("plot")
    (where / "served.toml").write_text(SERVED)
    (where / "meter.toml").write_text(LOGGED)
    db = where / "log.sqlite"
    with SimulatorProcess(["--map", str(where / "served.toml"), "plot-meter:1",
                           "--tcp", "127.0.0.1:0"], quiet=True) as sim:
        r = run_pymb("log", "--map", str(where / "meter.toml"), "--tcp", sim.endpoint,
                     "plot-meter:1", "--seconds", "1.5", "--out", str(db), "--quiet")
    assert r.returncode == 0, r.stderr
    return db, where


@pytest.mark.parametrize(("quantity", "says"), [
    ("model_name", "plot-meter-1's model_name is text, not a number"),
    ("missing_a", "plot-meter-1's missing_a has no value in"),
])
def test_nothing_to_draw_is_said_and_exits_non_zero(logged: tuple[Path, Path], tmp_path: Path,
                                                    quantity: str, says: str) -> None:
    db, _ = logged
    r = run_pymb("plot", str(db), "plot-meter-1", quantity, cwd=tmp_path)
    no_traceback(r)
    assert r.returncode == 2, r.stderr
    assert len(r.stderr.splitlines()) == 1, r.stderr
    assert says in r.stderr, r.stderr
    assert list(tmp_path.iterdir()) == []


def test_a_point_with_values_is_drawn(logged: tuple[Path, Path], tmp_path: Path) -> None:
    db, _ = logged
    r = run_pymb("plot", str(db), "plot-meter-1", "voltage_v", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "plot-meter-1-voltage_v.png").stat().st_size > 1000


def test_the_install_hint_runs(logged: tuple[Path, Path], tmp_path: Path) -> None:
    """Without matplotlib the command names a pip command for the Python that
    runs pymb; that command, dry-run, is one pip accepts here (matplotlib is
    installed for the tests, so pip has nothing to fetch)."""
    db, _ = logged
    code = ("import sys, runpy\n"
            "sys.modules['matplotlib'] = None  # as if the plot extra were not installed\n"
            "sys.argv = ['pymb', 'plot', sys.argv[1], 'plot-meter-1', 'voltage_v']\n"
            "runpy.run_module('pymb', run_name='__main__')\n")
    done = subprocess.run([sys.executable, "-c", code, str(db)], capture_output=True,
                          text=True, env=PYMB_ENV, cwd=tmp_path, timeout=120, check=False)
    assert done.returncode == 2
    head = "pymb plot: drawing needs matplotlib: "
    assert done.stderr.startswith(head), done.stderr
    hint = shlex.split(done.stderr[len(head):].strip())
    assert hint[:4] == [sys.executable, "-m", "pip", "install"], hint
    assert any(h.startswith("matplotlib") for h in hint[4:]), hint
    assert "pymb-modbus" not in done.stderr
    ran = subprocess.run([*hint[:4], "--dry-run", "--no-index", *hint[4:]],
                         capture_output=True, text=True, timeout=300, check=False)
    assert ran.returncode == 0, ran.stdout + ran.stderr
    assert "already satisfied" in ran.stdout, ran.stdout
