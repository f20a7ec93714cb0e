"""Damaged databases as the field meets them (one zeroed page in the middle of
a large file, a damaged header, a truncated file): ``pymb log`` never writes
into one, keeps it aside and logs on in a new file; ``pymb salvage`` copies
every row that can be read into a new file, never touching the damaged one."""

from __future__ import annotations

import hashlib
import os
import signal
import sqlite3
import subprocess
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from conftest import PYMB, PYMB_ENV, run_pymb
from docblocks import assert_shaped, claim_one
from hypothesis import given, settings
from hypothesis import strategies as st

from pymb.sim import SimulatorProcess
from pymb.store.damage import damage
from pymb.store.pages import fits, leaf_rows


def _page(path: Path) -> int:
    """The file's page size, from its header (a zeroed page is one of its pages)."""
    with open(path, "rb") as f:
        f.seek(16)
        size = int.from_bytes(f.read(2), "big")
    return 65536 if size == 1 else size


@pytest.fixture(scope="module")
def coolpro() -> Iterator[str]:
    """A simulated CoolPro (address 40) on Modbus TCP: HOST:PORT."""
    sim = SimulatorProcess(["coolpro", "hub:250", "--tcp", "127.0.0.1:0"], quiet=True).start()
    try:
        yield sim.endpoint
    finally:
        sim.stop()


@pytest.fixture(scope="module")
def intact(coolpro: str, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A database pymb log wrote (a hub and a CoolPro), grown to about 10 MB by
    copying its samples with SQLite (as weeks of logging would)."""
    db = tmp_path_factory.mktemp("intact") / "data.sqlite"
    r = run_pymb("log", "--tcp", coolpro, "--device", "hub:250", "--device", "coolpro:40",
                 "--interval", "0", "--seconds", "3", "--out", str(db), "--quiet", timeout=120)
    assert r.returncode == 0, r.stderr
    con = sqlite3.connect(db)
    for _ in range(10):
        if con.execute("SELECT COUNT(*) FROM samples").fetchone()[0] >= 8000:
            break
        con.execute("INSERT INTO samples(device_id, time_utc, monotonic, registers, "
                    "unsupported) SELECT device_id, time_utc, monotonic, registers, "
                    "unsupported FROM samples")
        con.commit()
    con.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    con.close()
    for side in ("-wal", "-shm"):
        Path(f"{db}{side}").unlink(missing_ok=True)
    assert db.stat().st_size > 5_000_000
    return db


def _zero_page(path: Path) -> None:
    """One page in the middle of the file overwritten with zeros."""
    page = _page(path)
    pages = path.stat().st_size // page
    with open(path, "r+b") as f:
        f.seek(pages // 2 * page)
        f.write(bytes(page))


def _bad_header(path: Path) -> None:
    """The first 100 bytes (SQLite's header) overwritten."""
    with open(path, "r+b") as f:
        f.write(bytes(range(100)))


def _truncated(path: Path) -> None:
    """The file cut to half of its pages (a copy that stopped, a full card)."""
    page = _page(path)
    os.truncate(path, path.stat().st_size // page // 2 * page)


def _zero_root(path: Path) -> None:
    """The samples table's root page (an interior page of its b-tree) zeroed."""
    con = sqlite3.connect(f"file:{path}?mode=ro&immutable=1", uri=True)
    try:
        (root,) = con.execute("SELECT rootpage FROM sqlite_master "
                              "WHERE name = 'samples'").fetchone()
    finally:
        con.close()
    size = _page(path)
    with open(path, "r+b") as f:
        f.seek((int(root) - 1) * size)
        f.write(bytes(size))


DAMAGES: dict[str, Callable[[Path], None]] = {
    "zeroed page": _zero_page, "damaged header": _bad_header, "truncated": _truncated,
    "zeroed root page": _zero_root}


def _damaged(intact: Path, tmp_path: Path, how: str) -> Path:
    db = tmp_path / "data.sqlite"
    db.write_bytes(intact.read_bytes())
    DAMAGES[how](db)
    return db


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _rows(path: Path, sql: str) -> list[tuple[object, ...]]:
    con = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    try:
        return con.execute(sql).fetchall()
    finally:
        con.close()


@pytest.mark.parametrize("how", list(DAMAGES))
def test_log_keeps_a_damaged_file_aside_and_logs_on(intact: Path, coolpro: str,
                                                     tmp_path: Path, how: str) -> None:
    db = _damaged(intact, tmp_path, how)
    before = _digest(db)
    size = db.stat().st_size
    r = run_pymb("log", "--tcp", coolpro, "--device", "coolpro:40", "--interval", "0.05",
                 "--seconds", "1.5", "--out", db.name, timeout=120, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    said = [line for line in r.stderr.splitlines() if "is damaged" in line]
    assert len(said) == 1, r.stderr
    if how == "zeroed page":  # the line docs/reliability.md shows
        assert_shaped(claim_one("docs/reliability.md", "text", how="compare",
                                contains="moved aside to"), said)
    aside = [p for p in tmp_path.iterdir() if p.name.startswith("data.sqlite.damaged-")]
    # nothing made beside it either (a -wal, a -shm)
    assert len(aside) == 1, sorted(p.name for p in tmp_path.iterdir())
    assert aside[0].name in said[0]
    assert "pymb salvage" in said[0]
    assert _digest(aside[0]) == before  # kept, never written
    # the new file: pymb's, sound, with the run's samples and the event that says so
    assert _rows(db, "PRAGMA quick_check") == [("ok",)]
    ids = [int(str(i)) for (i,) in _rows(db, "SELECT id FROM samples")]
    assert ids
    assert min(ids) > size // 8  # above any id the damaged file may hold
    events = _rows(db, "SELECT message FROM events WHERE kind = 'damaged'")
    assert len(events) == 1
    assert aside[0].name in str(events[0][0])


def test_a_document_that_is_not_pymb_is_still_refused(tmp_path: Path, coolpro: str) -> None:
    doc = tmp_path / "notes.sqlite"
    doc.write_bytes(b"my notes\n" * 1000)
    r = run_pymb("log", "--tcp", coolpro, "--device", "coolpro:40", "--seconds", "1",
                 "--out", str(doc))
    assert r.returncode == 2
    assert "is not a SQLite database" in r.stderr
    assert doc.read_bytes() == b"my notes\n" * 1000
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.sqlite"]


def _same_rows(new: Path, intact: Path) -> tuple[int, int]:
    """(rows of ``new``'s samples, rows of ``intact``'s): every row of ``new``
    is the intact file's row of that id, byte for byte."""
    got = {r[0]: r for r in _rows(new, "SELECT id, device_id, time_utc, monotonic, "
                                       "registers, unsupported FROM samples")}
    want = {r[0]: r for r in _rows(intact, "SELECT id, device_id, time_utc, monotonic, "
                                           "registers, unsupported FROM samples")}
    assert all(want[i] == row for i, row in got.items())
    return len(got), len(want)


@pytest.mark.parametrize("how", list(DAMAGES))
def test_salvage_copies_every_readable_row_and_never_touches_the_damaged_file(
        intact: Path, tmp_path: Path, how: str) -> None:
    db = _damaged(intact, tmp_path, how)
    before = _digest(db)
    new = tmp_path / "new.sqlite"
    r = run_pymb("salvage", str(db), str(new), timeout=300)
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    assert _digest(db) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data.sqlite", "new.sqlite"]
    assert _rows(new, "PRAGMA quick_check") == [("ok",)]
    got, want = _same_rows(new, intact)
    if how == "zeroed page":
        # one page of ~1.5 KB hub samples: a handful lost, said as ids
        assert want - 20 <= got < want
        assert "samples: skipped unreadable ids" in r.stderr
    elif how == "truncated":
        # the rows on the pages that are left, read through what is left of the
        # b-tree or, where its upper pages were cut off, from the pages
        assert want * 0.3 < got < want * 0.7
        assert "skipped unreadable ids" in r.stderr
    elif how == "zeroed root page":
        # an interior page holds no rows: every one is read (from the leaves)
        assert got == want
    else:
        assert got == want
        assert "header was damaged" in r.stderr
    assert len(_rows(new, "SELECT id FROM devices")) == 2
    # the salvaged file is a pymb database: info and export read it as any other
    info = run_pymb("info", str(new))
    assert info.returncode == 0, info.stderr
    assert f"{got:,}" in info.stdout


def test_salvage_never_writes_over_a_file(intact: Path, tmp_path: Path) -> None:
    db = _damaged(intact, tmp_path, "zeroed page")
    keep = tmp_path / "keep.sqlite"
    keep.write_bytes(b"precious")
    r = run_pymb("salvage", str(db), str(keep))
    assert r.returncode == 2
    assert "exists" in r.stderr
    assert keep.read_bytes() == b"precious"


def test_salvage_of_a_database_that_is_not_pymb_logs_says_whose_it_is(
        tmp_path: Path) -> None:
    """A readable SQLite file of another kind is named as such, not as one
    whose "list of tables cannot be read"; it is left as it was."""
    from pymb.collect.sqlstore import SqliteStore
    collected = tmp_path / "fleet.sqlite"
    SqliteStore(str(collected)).close()
    other = tmp_path / "other.sqlite"
    with sqlite3.connect(other) as con:
        con.execute("CREATE TABLE notes (body TEXT)")
    con.close()
    for db, said in ((collected, f"{collected} is what pymb collect writes, not pymb log: "
                                 "salvage copies pymb log's databases"),
                     (other, f"{other} is not a pymb database")):
        before = _digest(db)
        r = run_pymb("salvage", str(db), str(tmp_path / "new.sqlite"))
        assert (r.returncode, r.stdout, r.stderr) == (2, "", f"pymb salvage: {said}\n")
        assert _digest(db) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fleet.sqlite", "other.sqlite"]


def test_salvage_into_a_folder_name_writes_no_file(intact: Path, tmp_path: Path) -> None:
    """NEW given as a folder that does not exist yet (``rescued/``) is refused,
    not written as a file named ``rescued``."""
    r = run_pymb("salvage", str(intact), str(tmp_path / "rescued") + "/")
    assert (r.returncode, r.stdout) == (2, "")
    assert r.stderr == (f"pymb salvage: {tmp_path / 'rescued'}/ names a folder; give the new "
                        "database's file name\n")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.ctrl_c
def test_ctrl_c_during_a_salvage_leaves_no_file_behind(intact: Path, tmp_path: Path) -> None:
    """Interrupted while it writes the new database (its hidden file in the
    making is there), salvage exits 130 and leaves the folder as it found it:
    no half-written file, no hidden one."""
    src = tmp_path / "damaged"
    src.mkdir()
    db = _damaged(intact, src, "zeroed page")
    out = tmp_path / "out"
    out.mkdir()
    proc = subprocess.Popen([*PYMB, "salvage", str(db), str(out / "rescued.sqlite")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=PYMB_ENV)
    making = out / ".rescued.sqlite.salvage"
    deadline = time.monotonic() + 120
    while not making.exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.005)
    assert making.exists(), "salvage never began its new file"
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    assert list(out.iterdir()) == []


@pytest.mark.parametrize("how", list(DAMAGES))
def test_export_and_info_read_what_can_be_read_and_say_what_was_skipped(
        intact: Path, tmp_path: Path, how: str) -> None:
    db = _damaged(intact, tmp_path, how)
    before = _digest(db)
    out = tmp_path / "out.csv"
    r = run_pymb("export", str(db), "--csv", str(out), "--layout", "wide", timeout=300)
    assert r.returncode == 0, r.stderr
    assert "is damaged" in r.stderr
    lines = out.read_text().splitlines()
    want = len(_rows(intact, "SELECT id FROM samples"))
    if how == "zeroed page":
        assert "skipped unreadable ids" in r.stderr
        assert want - 20 <= len(lines) - 1 < want
    elif how == "truncated":
        assert "skipped unreadable ids" in r.stderr
        assert want * 0.3 < len(lines) - 1 < want * 0.7
    else:
        assert len(lines) - 1 == want
    info = run_pymb("info", str(db), timeout=300)
    assert info.returncode == 0, info.stderr
    assert "is damaged" in info.stderr
    assert info.stdout.startswith(f"{db}: pymb database")
    assert _digest(db) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data.sqlite", "out.csv"]


def _zero_leaf_of_oldest_samples(path: Path) -> None:
    """Zero a leaf page of the samples table among the oldest rows (where a
    trim starts), found with SQLite's dbstat table."""
    con = sqlite3.connect(path)
    try:
        (page,) = con.execute("SELECT pageno FROM dbstat WHERE name = 'samples' AND "
                              "pagetype = 'leaf' ORDER BY pageno LIMIT 1 OFFSET 3").fetchone()
    finally:
        con.close()
    size = _page(path)
    with open(path, "r+b") as f:
        f.seek((int(page) - 1) * size)
        f.write(bytes(size))


def test_a_trim_through_a_bad_page_moves_the_file_aside_and_the_restart_logs_on(
        intact: Path, coolpro: str, tmp_path: Path) -> None:
    """Damage the start's check did not reach (its bound: PYMB_CHECK_SECONDS=0
    stands for a large file on a slow card) met by the trim of --max-mb."""
    db = tmp_path / "data.sqlite"
    db.write_bytes(intact.read_bytes())
    _zero_leaf_of_oldest_samples(db)
    before = _digest(db)
    argv = ["log", "--tcp", coolpro, "--device", "coolpro:40", "--interval", "0.05",
            "--seconds", "1.5", "--out", str(db), "--max-mb", "3"]
    r = run_pymb(*argv, env={**PYMB_ENV, "PYMB_CHECK_SECONDS": "0"}, timeout=120)
    assert r.returncode == 5, r.stderr
    assert "the database is damaged" in r.stderr
    assert "moved aside to data.sqlite.damaged-" in r.stderr
    assert "Traceback" not in r.stderr
    aside = [p for p in tmp_path.iterdir() if p.name.startswith("data.sqlite.damaged-")
             and not p.name.endswith(("-wal", "-shm"))]
    assert len(aside) == 1
    # the restart (as the unit does after exit 5) logs into the new file
    r = run_pymb(*argv, timeout=120)
    assert r.returncode == 0, r.stderr
    assert _rows(db, "PRAGMA quick_check") == [("ok",)]
    assert int(str(_rows(db, "SELECT COUNT(*) FROM samples")[0][0])) > 0
    # the damaged file kept as it was: the trim's deletions were in its WAL,
    # rolled back when it met the bad page
    assert _digest(aside[0]) == before


@settings(max_examples=200, deadline=None)
@given(st.binary(min_size=0, max_size=3 * 1024))
def test_page_reader_takes_any_bytes(data: bytes) -> None:
    """The page reader parses what a damaged file holds: any bytes give rows
    or nothing, never an exception."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "x.sqlite"
        head = bytearray(b"SQLite format 3\x00" + data[:84].ljust(84, b"\x00"))
        head[16:18] = (1024).to_bytes(2, "big")
        path.write_bytes(bytes(head) + data)
        for rowid, values in leaf_rows(path):
            assert isinstance(rowid, int)
            assert isinstance(values, list)


def test_page_reader_reads_every_row_sqlite_reads(intact: Path) -> None:
    """The leaf pages of a sound file, read by the page reader, hold every
    sample SQLite reads, value for value, and nothing that is not a sample
    fits the samples table's columns."""
    con = sqlite3.connect(f"file:{intact}?mode=ro&immutable=1", uri=True)
    try:
        info = con.execute("PRAGMA table_info(samples)").fetchall()
        want = {r[0]: list(r) for r in con.execute("SELECT * FROM samples")}
    finally:
        con.close()
    shape = [(str(r[2]), bool(r[3]), bool(r[5])) for r in info]
    got: dict[int, list[object]] = {}
    for rowid, values in leaf_rows(intact):
        if fits(values, shape):
            values[0] = rowid
            got[rowid] = values
    assert got == want


def test_damage_that_quick_check_lists_is_said_in_one_line(intact: Path, tmp_path: Path) -> None:
    """quick_check's first row starts "*** in database main ***" and a newline:
    the damage is still one line of stderr and of the event."""
    db = tmp_path / "data.sqlite"
    db.write_bytes(intact.read_bytes())
    page = _page(db)
    with open(db, "r+b") as f:  # four pages in the middle: rows quick_check lists
        f.seek(db.stat().st_size // page // 2 * page)
        f.write(bytes(4 * page))
    found = damage(db, 60.0)
    assert found is not None
    assert "in database main" in found
    assert "\n" not in found
