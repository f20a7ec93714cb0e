""".ci/run's order as docs/install.md tells it, run for real with its tools
stubbed (setup, make, the .ci/check-* scripts and the venv's python only log
what they were asked): the C checks run as one background job, which without
pytest arguments also runs pytest on tests/c, tests/maps and tests/packaging
while the foreground pytest leaves them out; the job's log follows pytest's,
and a failure of the job fails the run before the Ctrl-C tests."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest
from conftest import ROOT

BG_TESTS = ["tests/c", "tests/maps", "tests/packaging"]
CHECKS = ["check-c-install", "check-abi", "check-arm", "check-sdist"]

pytestmark = pytest.mark.skipif(shutil.which("setsid") is None, reason="needs setsid")


def _stub(path: Path, body: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(f"#!/bin/sh\n{body}\n")
    path.chmod(0o755)


def _run(tmp_path: Path, *args: str, fail: str = "") -> tuple[subprocess.CompletedProcess[str],
                                                               list[str]]:
    """.ci/run ARGS in a tree of stubs; ``fail``: the check that exits 3."""
    tree = tmp_path / "tree"
    (tree / ".ci").mkdir(parents=True)
    shutil.copy2(ROOT / ".ci" / "run", tree / ".ci" / "run")
    calls = tmp_path / "calls.log"
    _stub(tree / ".ci" / "setup", f'echo "setup $*" >> {calls}')
    for name in CHECKS:
        code = 3 if name == fail else 0
        _stub(tree / ".ci" / name, f'echo "{name}" >> {calls}; exit {code}')
    _stub(tree / ".venv" / "bin" / "python", f'echo "python $*" >> {calls}')
    _stub(tmp_path / "bin" / "make", f'echo "make $*" >> {calls}')
    env = dict(os.environ, PATH=f"{tmp_path / 'bin'}{os.pathsep}{os.environ['PATH']}")
    env.pop("FUZZ_SECONDS", None)
    r = subprocess.run([str(tree / ".ci" / "run"), *args], env=env, capture_output=True,
                       text=True, timeout=120, check=False)
    return r, calls.read_text().splitlines()


def test_the_c_checks_and_the_cpu_bound_tests_run_in_the_background(tmp_path: Path) -> None:
    r, calls = _run(tmp_path)
    assert r.returncode == 0, r.stdout + r.stderr
    pytests = [c for c in calls if c.startswith("python -m pytest")]
    fg = ("python -m pytest -n 3 --dist worksteal --durations=15 "
          + " ".join(f"--ignore {d}" for d in BG_TESTS))
    assert fg in pytests
    (bg,) = [c for c in pytests if c.endswith(" ".join(BG_TESTS))]
    assert bg.startswith("python -m pytest -p no:cacheprovider --basetemp /")
    # the Ctrl-C tests run last, after the background job ended
    assert pytests[-1] == 'python -m pytest -q -m ctrl_c and not slow and not timing'
    for c in ["make -C csrc check", "make -C csrc sanitize",
              "make -C csrc fuzz-run FUZZ_SECONDS=15", *CHECKS]:
        assert c in calls, c
    assert calls.index("make -C csrc all") < calls.index("make -C csrc check")
    assert calls.index(bg) > calls.index("check-sdist")  # after the C checks
    # the job's log follows pytest's
    out = r.stdout
    assert out.index("== Background job: waiting for it") < out.index("== C library (")
    assert out.index("== C library (") < out.index("== Ctrl-C tests")


def test_a_failed_background_check_fails_the_run(tmp_path: Path) -> None:
    r, calls = _run(tmp_path, fail="check-arm")
    assert r.returncode == 1, r.stdout + r.stderr
    assert "the background job failed (exit 3): see its log above" in r.stderr
    assert "check-sdist" not in calls  # the job stopped at its failure
    assert not any("ctrl_c" in c for c in calls)
    assert "== ARM (arm64, armhf under qemu-user)" in r.stdout


def test_pytest_arguments_run_as_asked_in_the_foreground(tmp_path: Path) -> None:
    r, calls = _run(tmp_path, "tests/cli", "-x")
    assert r.returncode == 0, r.stdout + r.stderr
    pytests = [c for c in calls if c.startswith("python -m pytest")]
    assert pytests == ["python -m pytest -n 3 --dist worksteal --durations=15 tests/cli -x",
                       'python -m pytest -q -m ctrl_c and not slow and not timing']
    assert "check-arm" in calls
