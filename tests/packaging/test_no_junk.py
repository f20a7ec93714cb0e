"""The repository tracks no scratch output, and .gitignore keeps it out."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

from pymb.bench import wear

ROOT = Path(__file__).resolve().parents[2]


def _git(*args: str) -> str:
    return subprocess.run(["git", "-C", str(ROOT), *args], capture_output=True, text=True,
                          check=True).stdout


@pytest.mark.skipif(shutil.which("git") is None or not (ROOT / ".git").exists(),
                    reason="not a git checkout")
def test_no_scratch_files_are_tracked() -> None:
    junk = [p for p in _git("ls-files").splitlines()
            if p.endswith((".reserve", ".strace", ".sqlite", ".sqlite-wal", ".sqlite-shm"))
            or p.startswith("pymb-bench-")]
    assert junk == []


@pytest.mark.skipif(shutil.which("git") is None or not (ROOT / ".git").exists(),
                    reason="not a git checkout")
@pytest.mark.parametrize("name", [".x.sqlite.reserve", "pymb-bench-wear-abc/y.strace",
                                  "pymb-demo-20261203-120000-1.sqlite"])
def test_gitignore_keeps_scratch_out(name: str) -> None:
    r = subprocess.run(["git", "-C", str(ROOT), "check-ignore", "-q", "--no-index", name])
    assert r.returncode == 0, name


def test_the_wear_bench_scratch_folder_is_a_temp_folder_on_a_disk() -> None:
    where = wear._disk_temp()
    assert where in ("/var/tmp", __import__("tempfile").gettempdir())
    assert not where.startswith(str(ROOT))
