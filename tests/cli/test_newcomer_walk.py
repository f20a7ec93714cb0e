"""What a new user meets walking through the README and the guides a second
time: a command run again on its own output, a slip in a map's name."""

from __future__ import annotations

import re
import sqlite3
from pathlib import Path

from conftest import run_pymb


def test_demo_into_an_earlier_demos_database_counts_this_runs_faults(tmp_path: Path) -> None:
    """docs/data.md's ``pymb demo --out demo.sqlite`` run twice: the second
    summary's faults by kind are its own run's, not every run's in the file."""
    db = tmp_path / "demo.sqlite"
    r = run_pymb("demo", "--seconds", "1", "--quiet", "--out", str(db), timeout=120)
    assert r.returncode == 0, r.stderr
    con = sqlite3.connect(db)
    with con:  # an earlier run's 40 timeouts, an hour before
        con.executemany("INSERT INTO events(time_utc, monotonic, bus, kind, message) "
                        "VALUES (strftime('%s', 'now') - 3600, 0, 'psu', 'timeout', 'old')",
                        [()] * 40)
    con.close()
    r = run_pymb("demo", "--seconds", "1", "--quiet", "--out", str(db), timeout=120)
    assert r.returncode == 0, r.stderr
    seen = re.search(r"faults seen: (\d+)(?: \((.*)\))?\n", r.stdout)
    assert seen is not None, r.stdout
    by_kind = sum(int(n) for n in re.findall(r"(\d+) \w+", seen.group(2) or ""))
    assert by_kind < 40, seen.group(0)
