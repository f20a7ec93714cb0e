"""Durable within seconds, at any rate: a slow log (a CoolPro read every
second, the rate the old commit rule kept for up to 30 minutes) is in the
file, for readers and after a kill, at most 2 s after each read.

Real processes: ``pymb log`` against a simulated CoolPro on Modbus TCP in
its own process, readers through their own SQLite connections, real signals
(SIGSTOP as a hung process a watchdog finds, then SIGKILL as the watchdog or
the OOM killer sends it). A power cut is tests/logger/test_power_cut.py.
"""

from __future__ import annotations

import shutil
import signal
import sqlite3
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import PYMB, PYMB_ENV, wait_until
from eventlines import without_events

from pymb.sim import SimulatorProcess

LOSS_BOUND = 2.0  #: seconds of samples a kill may take back (docs/reliability.md)


@pytest.fixture
def coolpro() -> Iterator[str]:
    """A simulated CoolPro on Modbus TCP in its own process: HOST:PORT."""
    sim = SimulatorProcess(["coolpro:40", "--tcp", "127.0.0.1:0"], quiet=True).start()
    try:
        yield sim.endpoint
    finally:
        sim.stop()


def _slow_log(endpoint: str, db: Path, *extra: str) -> subprocess.Popen[str]:
    """``pymb log`` of the CoolPro every second, the default commit rule."""
    return subprocess.Popen([*PYMB, "log", "coolpro:40", "--tcp", endpoint, "--interval", "1",
                             "--out", str(db), "--quiet", *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=PYMB_ENV)


def _times(db: Path) -> dict[int, float]:
    """id -> time_utc of every committed sample, through a reader's own connection."""
    if not db.exists():
        return {}
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=10)
    try:
        return {int(i): float(t) for i, t in con.execute("SELECT id, time_utc FROM samples")}
    except sqlite3.OperationalError:  # the schema not made yet
        return {}
    finally:
        con.close()


def _kill(proc: subprocess.Popen[str]) -> None:
    if proc.poll() is None:
        proc.kill()
    proc.communicate(timeout=30)


def test_a_reader_sees_each_sample_of_a_slow_log_within_two_seconds(
        coolpro: str, tmp_path: Path) -> None:
    db = tmp_path / "data.sqlite"
    proc = _slow_log(coolpro, db)
    first_seen: dict[int, float] = {}
    try:
        def enough() -> bool:
            now = time.time()
            for i in _times(db).keys() - first_seen.keys():
                first_seen[i] = now
            return len(first_seen) >= 8

        wait_until(enough, lambda: f"8 samples committed, saw {len(first_seen)}", 60,
                   alive=lambda: proc.poll() is None, every=0.05)
    finally:
        _kill(proc)
    stamped = _times(db)
    late = {i: round(first_seen[i] - stamped[i], 2) for i in first_seen
            if first_seen[i] - stamped[i] > LOSS_BOUND}
    assert not late, f"samples a reader saw more than {LOSS_BOUND:g} s after their read: {late}"


def test_a_watchdog_kill_of_a_hung_logger_loses_at_most_two_seconds(
        coolpro: str, tmp_path: Path) -> None:
    """A logger that hangs (SIGSTOP: no more watchdog pings) and is killed
    when the watchdog's time is up (SIGKILL) keeps every sample read up to
    2 s before it hung."""
    db = tmp_path / "data.sqlite"
    proc = _slow_log(coolpro, db)
    try:
        wait_until(lambda: len(_times(db)) >= 5, "5 samples committed", 60,
                   alive=lambda: proc.poll() is None, every=0.1)
        time.sleep(1.3)  # somewhere between two commits
        proc.send_signal(signal.SIGSTOP)
        hung_at = time.time()
        time.sleep(3.0)  # the watchdog's time (60 s in a unit) changes nothing
        proc.kill()
    finally:
        _kill(proc)
    kept = _times(db)
    newest = max(kept.values())
    assert hung_at - newest <= LOSS_BOUND, (
        f"the newest sample kept was read {hung_at - newest:.2f} s before the logger hung")


def test_a_removed_directory_ends_a_slow_log_within_seconds(
        coolpro: str, tmp_path: Path) -> None:
    where = tmp_path / "state"
    where.mkdir()
    db = where / "data.sqlite"
    proc = _slow_log(coolpro, db)
    try:
        wait_until(lambda: len(_times(db)) >= 2, "2 samples committed", 60,
                   alive=lambda: proc.poll() is None, every=0.1)
        shutil.rmtree(where)
        removed = time.monotonic()
        wait_until(lambda: proc.poll() is not None, "the logger to notice the removal", 30,
                   every=0.05)
        noticed = time.monotonic() - removed
        _, err = proc.communicate(timeout=30)
    finally:
        _kill(proc)
    assert proc.returncode == 5, err
    lines = without_events(err)
    assert len(lines) == 1, err
    assert "was removed" in lines[0], err
    # the commit interval and a turn of the loop, with room for a loaded machine
    assert noticed <= 5.0, f"noticed {noticed:.1f} s after the removal"



def test_a_removed_directory_ends_a_log_with_nothing_to_commit_within_seconds(
        coolpro: str, tmp_path: Path) -> None:
    """A device polled once a minute: after its first sample the logger has
    nothing to commit for a minute, and still notices the removal."""
    where = tmp_path / "state"
    where.mkdir()
    db = where / "data.sqlite"
    proc = _slow_log(coolpro, db, "--interval", "60")
    try:
        wait_until(lambda: len(_times(db)) >= 1, "the first sample committed", 60,
                   alive=lambda: proc.poll() is None, every=0.1)
        time.sleep(2.0)  # nothing more to commit
        shutil.rmtree(where)
        removed = time.monotonic()
        wait_until(lambda: proc.poll() is not None, "the logger to notice the removal", 30,
                   every=0.05)
        noticed = time.monotonic() - removed
        _, err = proc.communicate(timeout=30)
    finally:
        _kill(proc)
    assert proc.returncode == 5, err
    assert "was removed" in err, err
    assert noticed <= 5.0, f"noticed {noticed:.1f} s after the removal"
