"""The page layout a commit writes: 2 KB pages for a new database (a commit
of a few rows writes about half of what 4 KB pages did) without
pointer-map pages, a hub sweep still on one page (no overflow page, whose
content SQLite's checks do not read), a file made with 4 KB pages or with
incremental vacuum kept as it is and logged on, and a lower size limit
shrinking either kind of file."""

from __future__ import annotations

import os
import sqlite3
import struct
import subprocess
import sys
import time
from array import array
from pathlib import Path

import pytest

pytest.register_assert_rewrite("disks")
from disks import Tmpfs, need_root  # noqa: E402

from pymb.devices import decode_hub  # noqa: E402
from pymb.store import DeviceInfo, Sample, SqliteSink  # noqa: E402
from pymb.store.schema import install  # noqa: E402

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
    assert _pragma(db, "auto_vacuum") == 0  # no pointer-map page for each commit to rewrite
    con = sqlite3.connect(db)
    try:
        kinds = {t for (t,) in con.execute(
            "SELECT DISTINCT pagetype FROM dbstat WHERE name = 'samples'")}
        assert con.execute("SELECT COUNT(*) FROM samples").fetchone()[0] == 40
        assert con.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    finally:
        con.close()
    assert "overflow" not in kinds, kinds


def _commits(wal: bytes) -> list[list[int]]:
    """The page numbers each commit wrote, from a WAL's frame headers (a
    32-byte file header, then frames: page number, the database's size in
    pages on a commit's last frame or 0, salts and checksums, the page)."""
    (page,) = struct.unpack(">I", wal[8:12])
    out: list[list[int]] = []
    pages: list[int] = []
    for at in range(32, len(wal) - page - 23, page + 24):
        number, size = struct.unpack(">II", wal[at:at + 8])
        pages.append(number)
        if size:
            out.append(pages)
            pages = []
    return out


def test_a_commit_of_two_hub_sweeps_writes_at_most_five_2_kb_pages(tmp_path: Path) -> None:
    """What a hub polled every second writes to the WAL per commit: the two
    sweeps' leaf pages, their parent, the time index's leaf and the header
    (page 1); no pointer-map page (with one: six; with 4 KB pages about
    23 KB a commit)."""
    db = tmp_path / "wal.sqlite"
    sink = SqliteSink(db)
    _sweeps(sink, 0, 10)  # the b-trees past their first pages
    wal = Path(f"{db}-wal")
    before = len(_commits(wal.read_bytes()))
    commits = 50
    _sweeps(sink, 10, 2 * commits)
    written = _commits(wal.read_bytes())[before:]  # no checkpoint ran: 4 MB apart
    sink.close()
    assert len(written) == commits
    assert all(1 in pages and len(pages) <= 5 for pages in written), written
    assert sum(map(len, written)) / commits <= 5


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


def _filled(db: Path, n: int) -> None:
    """``n`` hub sweeps (one page each) logged without a size limit."""
    t0 = time.time() - 100_000
    sink = SqliteSink(db)
    sink.write_batch([Sample(HUB, t0 + i, float(i), decode_hub(
        array("H", [(i * 7 + k) & 0x7FFF for k in range(700)]))) for i in range(n)])
    sink.close()


def test_a_lower_size_limit_shrinks_the_file_either_layout(tmp_path: Path) -> None:
    """A file logged without a limit, opened with a lower one: trimmed to the
    newest samples and made smaller, whether it has pointer-map pages
    (incremental vacuum, as earlier pymb made files: a little at a time) or
    not (a new file: one VACUUM); then logged into, and intact."""
    for auto_vacuum in ("INCREMENTAL", None):
        db = tmp_path / f"{auto_vacuum}.sqlite"
        if auto_vacuum is not None:  # as the previous release made a file
            con = sqlite3.connect(db, isolation_level=None)
            con.execute("PRAGMA page_size = 2048")
            con.execute(f"PRAGMA auto_vacuum = {auto_vacuum}")
            install(con)
            con.close()
        _filled(db, 3000)
        assert os.path.getsize(db) > 6_000_000
        sink = SqliteSink(db, max_bytes=2_000_000)
        assert sink.trimmed > 0
        _sweeps(sink, 3000, 10)
        sink.close()
        assert os.path.getsize(db) <= 2_000_000, auto_vacuum
        assert _pragma(db, "auto_vacuum") == (2 if auto_vacuum else 0)
        con = sqlite3.connect(db)
        try:
            first, last, n = con.execute(
                "SELECT MIN(id), MAX(id), COUNT(*) FROM samples").fetchone()
            assert last == 3010
            assert n == last - first + 1 > 100, (first, last, n)
            assert con.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
        finally:
            con.close()


def test_a_lower_size_limit_without_room_for_the_copy_reuses_the_file(tmp_path: Path) -> None:
    """The VACUUM that shrinks a file without pointer-map pages copies the
    pages kept: on a disk without twice their size free the file keeps its
    size, its free pages take the next samples (it does not grow), and it
    shrinks at the next open with room. On a small tmpfs (needs root)."""
    need_root()
    with Tmpfs(tmp_path / "card", 20 * 1024) as card:
        db = card.mountpoint / "data.sqlite"
        _filled(db, 3000)
        size = os.path.getsize(db)
        assert size > 6_000_000
        # 1 MB free, and the 4 MB reserve the trim may give up: less than twice
        # the 2.6 MB a 3 MB limit keeps
        card.fill(leave=1 << 20)
        sink = SqliteSink(db, max_bytes=3_000_000)
        assert sink.trimmed > 0
        _sweeps(sink, 3000, 200)
        sink.close()
        assert os.path.getsize(db) == size
        (card.mountpoint / "filler").unlink()
        sink = SqliteSink(db, max_bytes=3_000_000)
        _sweeps(sink, 3200, 10)
        sink.close()
        assert os.path.getsize(db) <= 3_000_000
        con = sqlite3.connect(db)
        try:
            assert con.execute("SELECT MAX(id) FROM samples").fetchone()[0] == 3210
            assert con.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
        finally:
            con.close()


_OPEN = """import sys
from pymb.store import SqliteSink
sink = SqliteSink(sys.argv[1], max_bytes=3_000_000)
print(sink.trimmed)
sink.close()
"""


def test_a_vacuum_without_room_in_the_temporary_directory_keeps_the_file(
        tmp_path: Path) -> None:
    """The VACUUM builds its copy in SQLite's temporary directory, which may be
    another, smaller disk (a tmpfs /tmp) than the database's: when the copy
    finds no room there, the open goes on with the file as it is (it reuses
    its free pages), as on a disk without room for the copy. A process of
    its own with SQLITE_TMPDIR on a 256 KB tmpfs (needs root)."""
    need_root()
    db = tmp_path / "data.sqlite"
    _filled(db, 3000)
    size = os.path.getsize(db)
    with Tmpfs(tmp_path / "tmp", 256) as tmp:
        r = subprocess.run([sys.executable, "-c", _OPEN, str(db)], capture_output=True,
                           text=True, timeout=120, check=False,
                           env=dict(os.environ, SQLITE_TMPDIR=str(tmp.mountpoint)))
    assert r.returncode == 0, r.stderr
    assert int(r.stdout) > 0  # trimmed to the limit
    assert os.path.getsize(db) == size
    con = sqlite3.connect(db)
    try:
        assert con.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    finally:
        con.close()
    # with room for the copy, the next open makes it smaller
    r = subprocess.run([sys.executable, "-c", _OPEN, str(db)], capture_output=True,
                       text=True, timeout=120, check=False)
    assert r.returncode == 0, r.stderr
    assert os.path.getsize(db) <= 3_000_000
