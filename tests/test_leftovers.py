"""Small promises of the log and export commands: an empty --since is an
error, not "no filter"; what a kill during database creation leaves behind is
cleaned up by the next run."""

from __future__ import annotations

import re
import subprocess
import sys
from array import array
from pathlib import Path

import pytest
from conftest import PYMB_ENV, run_pymb

from pymb.devices import decode_hub
from pymb.store import DeviceInfo, Sample, SqliteSink


def _database(path: Path) -> None:
    sink = SqliteSink(path)
    sink.write(Sample(DeviceInfo("b", "p", "hub", 1, "hub-1"), 1_800_000_000.0, 1.0,
                      decode_hub(array("H", [0] * 700))))
    sink.close()


@pytest.mark.parametrize(("argv", "message"), [
    (["--since", ""], "--since needs an ISO 8601 time, got ''"),
    (["--since", " "], "--since needs an ISO 8601 time, got ' '"),
    (["--since", "yesterday"], "--since needs an ISO 8601 time, got 'yesterday'"),
    (["--device", ""], "no device ''"),
])
def test_export_refuses_an_empty_filter(tmp_path: Path, argv: list[str], message: str) -> None:
    db = tmp_path / "log.sqlite"
    _database(db)
    r = run_pymb("export", str(db), "--csv", "-", *argv, timeout=60)
    assert r.returncode == 2, r
    assert r.stdout == ""
    assert message in r.stderr
    assert "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def test_export_since_still_filters(tmp_path: Path) -> None:
    db = tmp_path / "log.sqlite"
    _database(db)
    for since, rows in (("2027-01-15T08:00:00Z", 700), ("2027-01-15T08:00:01Z", 0)):
        r = run_pymb("export", str(db), "--csv", "-", "--since", since, timeout=60)
        assert r.returncode == 0, r.stderr
        assert len(r.stdout.splitlines()) == 1 + rows


def test_a_kill_during_creation_leaves_nothing_the_next_run_keeps(tmp_path: Path) -> None:
    """A process SIGKILLed while it makes the database leaves its hidden
    ``.NAME.PID.creating``; the next run that opens NAME deletes it (its PID is
    gone), and keeps that of a process still running."""
    db = tmp_path / "log.sqlite"
    code = ("import os, signal, sqlite3, sys\n"
            "from pathlib import Path\n"
            "import pymb.store as s\n"
            "real = sqlite3.connect\n"
            "def connect(*a, **k):\n"
            "    con = real(*a, **k)\n"
            "    con.execute('CREATE TABLE half(x)')\n"
            "    os.kill(os.getpid(), signal.SIGKILL)\n"
            "sqlite3.connect = connect\n"
            "s.SqliteSink(sys.argv[1])\n")
    killed = subprocess.run([sys.executable, "-c", code, str(db)], env=PYMB_ENV, timeout=60,
                            capture_output=True)
    assert killed.returncode == -9, killed
    left = [p.name for p in tmp_path.iterdir()]
    assert len(left) == 1, left
    assert re.fullmatch(r"\.log\.sqlite\.[0-9]+\.creating", left[0]), left
    assert not db.exists()
    with subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"]) as alive:
        try:
            theirs = tmp_path / f".log.sqlite.{alive.pid}.creating"
            theirs.write_bytes(b"")
            _database(db)
            assert sorted(p.name for p in tmp_path.iterdir() if "creating" in p.name) == [
                theirs.name]
        finally:
            alive.kill()
    # and the next open, with that process gone, removes its file too
    SqliteSink(db).close()
    assert not [p for p in tmp_path.iterdir() if "creating" in p.name]

