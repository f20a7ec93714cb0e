"""``pymb salvage DAMAGED NEW`` where NEW cannot be written (a read-only file
system, a full disk): one line, no traceback, nothing left behind, DAMAGED
untouched."""

from __future__ import annotations

import sqlite3
import subprocess
from pathlib import Path

import pytest
from clikit import digest, no_traceback
from conftest import run_pymb
from disks import Tmpfs, need_root

import pymb.store.salvage as salvage_module
from pymb.errors import OutputError


def _salvage(db: Path, new: Path) -> subprocess.CompletedProcess[str]:
    r = run_pymb("salvage", str(db), str(new))
    no_traceback(r)
    assert len(r.stderr.splitlines()) == 1, r.stderr
    return r


def test_a_read_only_folder(logged: Path, tmp_path: Path) -> None:
    need_root()
    before = digest(logged)
    with Tmpfs(tmp_path / "ro", 1024) as ro:
        subprocess.run(["mount", "-o", "remount,ro", str(ro.mountpoint)], check=True,
                       timeout=60)
        r = _salvage(logged, ro.mountpoint / "new.sqlite")
        assert r.returncode == 2, r.stderr
        assert r.stderr == (f"pymb salvage: cannot write {ro.mountpoint / 'new.sqlite'}: "
                            "Read-only file system\n")
        assert list(ro.mountpoint.iterdir()) == []
    assert digest(logged) == before


def test_a_full_disk(logged: Path, tmp_path: Path) -> None:
    need_root()
    before = digest(logged)
    with Tmpfs(tmp_path / "card", 256) as card:
        filler = card.fill(leave=16 * 1024)
        r = _salvage(logged, card.mountpoint / "new.sqlite")
        assert r.returncode == 5, r.stderr
        assert r.stderr.startswith(f"pymb salvage: cannot write {card.mountpoint / 'new.sqlite'}"
                                   ": database or disk is full"), r.stderr
        assert list(card.mountpoint.iterdir()) == [filler]
    assert digest(logged) == before


def test_stdout_is_no_new_database(logged: Path, tmp_path: Path) -> None:
    """``pymb salvage DAMAGED -``: '-' is stdout elsewhere (export --csv -), not
    a file name to make in the current folder."""
    r = run_pymb("salvage", str(logged), "-", cwd=tmp_path)
    no_traceback(r)
    assert (r.returncode, r.stderr) == (
        2, "pymb salvage: NEW '-': salvage writes a new database file, not stdout; "
           "give its name\n")
    assert list(tmp_path.iterdir()) == []


def test_an_io_error_mid_copy_is_one_line(logged: Path, tmp_path: Path,
                                          monkeypatch: pytest.MonkeyPatch) -> None:
    """An SQLite failure that names neither file (a disk I/O error) stops
    the copy with the one-line output error, not a traceback; NEW is not
    made and DAMAGED is untouched."""
    def failing(*args: object) -> None:
        raise sqlite3.OperationalError("disk I/O error")

    monkeypatch.setattr(salvage_module, "_copy_all", failing)
    before = digest(logged)
    new = tmp_path / "new.sqlite"
    with pytest.raises(OutputError, match=r"^salvage into .*new\.sqlite stopped: disk I/O "
                                          r"error; nothing was written$"):
        salvage_module.salvage(str(logged), str(new))
    assert list(tmp_path.iterdir()) == []
    assert digest(logged) == before
