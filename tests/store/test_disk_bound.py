"""``--max-mb`` above the free space: the disk is the bound. ``pymb log``
keeps logging inside what the disk holds, reusing the file's own pages,
instead of filling the disk and exiting 5 at every restart.

Real processes (``pymb log`` against a simulated hub and CoolPro on Modbus
TCP in its own process) on a small tmpfs (tests/disks.py, needs root).
"""

from __future__ import annotations

import sqlite3
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import PYMB, PYMB_ENV, wait_until

pytest.register_assert_rewrite("disks")
from disks import Tmpfs, need_root  # noqa: E402

from pymb.sim import SimulatorProcess  # noqa: E402


@pytest.fixture
def devices() -> Iterator[str]:
    """A simulated hub and CoolPro on Modbus TCP in their own process: HOST:PORT."""
    sim = SimulatorProcess(["hub:1", "coolpro:40", "--tcp", "127.0.0.1:0"], quiet=True).start()
    try:
        yield sim.endpoint
    finally:
        sim.stop()


def _first_id(db: Path) -> int:
    if not db.exists():
        return 0
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=10)
    try:
        return int(con.execute("SELECT COALESCE(MIN(id), 0) FROM samples").fetchone()[0])
    except sqlite3.OperationalError:
        return 0
    finally:
        con.close()


def test_a_size_bound_above_the_free_space_logs_within_the_disk(
        devices: str, tmp_path: Path) -> None:
    need_root()
    with Tmpfs(tmp_path / "card", 24 * 1024) as card:
        card.fill(leave=12 << 20)  # 12 MB left; the bound says 100
        db = card.mountpoint / "data.sqlite"

        def run() -> tuple[int, str]:
            proc = subprocess.Popen([*PYMB, "log", "hub:1", "coolpro:40", "--tcp", devices,
                                     "--interval", "0", "--out", str(db), "--max-mb", "100",
                                     "--quiet"], stdout=subprocess.DEVNULL,
                                    stderr=subprocess.PIPE, text=True, env=PYMB_ENV)
            start = _first_id(db)

            try:
                # the disk holds about 8,000 hub sweeps: trims come within a minute
                wait_until(lambda: _first_id(db) > start + 2000,
                           "samples trimmed to stay on the disk", 120,
                           alive=lambda: proc.poll() is None, every=0.2)
            finally:
                if proc.poll() is None:
                    proc.terminate()
                _, err = proc.communicate(timeout=60)
            return proc.returncode, err

        code, err = run()
        assert code == 0, err
        code, err = run()  # a restart goes on in the same file, within the disk
        assert code == 0, err
        con = sqlite3.connect(db)
        try:
            assert con.execute("PRAGMA integrity_check").fetchone() == ("ok",)
        finally:
            con.close()
