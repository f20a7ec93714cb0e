"""A database appears whole: a process killed while it creates one leaves
nothing the next run keeps."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

from conftest import PYMB_ENV
from dbwait import one_sample_database

from pymb.store import SqliteSink


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
            one_sample_database(db)
            assert sorted(p.name for p in tmp_path.iterdir() if "creating" in p.name) == [
                theirs.name]
        finally:
            alive.kill()
    # and the next open, with that process gone, removes its file too
    SqliteSink(db).close()
    assert not [p for p in tmp_path.iterdir() if "creating" in p.name]
