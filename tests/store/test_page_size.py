"""The page layout a commit writes: 2 KB pages for a new database (a commit
of a few rows writes about half of what 4 KB pages did), a hub sweep still
on one page (no overflow page, whose content SQLite's checks do not read),
and a file made with 4 KB pages kept as it is and logged on."""

from __future__ import annotations

import os
import sqlite3
import time
from array import array
from pathlib import Path

from pymb.devices import decode_hub
from pymb.store import DeviceInfo, Sample, SqliteSink
from pymb.store.schema import install

HUB = DeviceInfo("b", "/dev/null", "hub", 1, "hub-1")


def _sweeps(sink: SqliteSink, start: int, n: int) -> None:
    """``n`` hub sweeps (1,400 bytes each), two per commit, as a hub polled
    every second commits them."""
    t0 = time.time() - 10_000
    for i in range(start, start + n):
        regs = array("H", [(i * 31 + k) & 0x7FFF for k in range(700)])
        sink.write(Sample(HUB, t0 + i, float(i), decode_hub(regs)))
        if i % 2:
            sink.commit()


def _pragma(db: Path, name: str) -> int:
    con = sqlite3.connect(db)
    try:
        return int(con.execute(f"PRAGMA {name}").fetchone()[0])
    finally:
        con.close()


def test_a_new_database_has_2_kb_pages_and_a_hub_sweep_fits_one(tmp_path: Path) -> None:
    db = tmp_path / "new.sqlite"
    sink = SqliteSink(db)
    _sweeps(sink, 0, 40)
    sink.close()
    assert _pragma(db, "page_size") == 2048
    assert _pragma(db, "auto_vacuum") == 2  # incremental: a lower --max-mb gives pages back
    con = sqlite3.connect(db)
    try:
        kinds = {t for (t,) in con.execute(
            "SELECT DISTINCT pagetype FROM dbstat WHERE name = 'samples'")}
        assert con.execute("SELECT COUNT(*) FROM samples").fetchone()[0] == 40
        assert con.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    finally:
        con.close()
    assert "overflow" not in kinds, kinds


def test_a_commit_of_two_hub_sweeps_writes_at_most_seven_2_kb_pages(tmp_path: Path) -> None:
    """What a hub polled every second writes to the WAL per commit: the two
    sweeps' leaf pages, their parent, the time index's leaf, the header and
    the pointer-map page (with 4 KB pages: about 23 KB a commit)."""
    db = tmp_path / "wal.sqlite"
    sink = SqliteSink(db)
    _sweeps(sink, 0, 10)  # the b-trees past their first pages
    wal = Path(f"{db}-wal")
    before = wal.stat().st_size
    commits = 50
    _sweeps(sink, 10, 2 * commits)
    per_commit = (wal.stat().st_size - before) / commits  # no checkpoint ran: 4 MB apart
    sink.close()
    assert 2 * 1400 < per_commit <= 7 * (2048 + 24), per_commit


def test_a_file_with_4_kb_pages_keeps_them_and_logs_on(tmp_path: Path) -> None:
    db = tmp_path / "old.sqlite"
    con = sqlite3.connect(db, isolation_level=None)  # as pymb 4 KB made a file
    con.execute("PRAGMA page_size = 4096")
    con.execute("PRAGMA auto_vacuum = INCREMENTAL")
    install(con)
    con.close()
    for start in (0, 20):  # written, closed, opened again
        sink = SqliteSink(db)
        _sweeps(sink, start, 20)
        sink.close()
    assert _pragma(db, "page_size") == 4096
    con = sqlite3.connect(db)
    try:
        assert con.execute("SELECT COUNT(*) FROM samples").fetchone()[0] == 40
        assert con.execute("SELECT COUNT(*) FROM hub").fetchone()[0] == 40 * 100
        assert con.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    finally:
        con.close()
    assert os.path.getsize(db) % 4096 == 0
