"""EACCES: ``pymb log`` run by a user who may not write its database.

Tests run as root, whom file modes do not stop: the logger runs here as an
unprivileged user (``setpriv`` to uid/gid 65534, ``nobody``) when the tests
run as root, and as the tests' own user otherwise (an owner cannot write a
file or directory of mode 0444/0555 either). Real processes against a
CoolPro simulated on Modbus TCP in its own process, on real directories.
"""

from __future__ import annotations

import os
import shutil
import signal
import sqlite3
import subprocess
import tempfile
from collections.abc import Iterator
from contextlib import closing
from pathlib import Path

import pytest
from conftest import PYMB, PYMB_ENV
from dbwait import wait_for
from eventlines import without_events

from pymb.sim import SimulatorProcess

NOBODY = 65534
SAMPLES = "SELECT COUNT(*) FROM samples"
ENV = {**PYMB_ENV, "PYTHONDONTWRITEBYTECODE": "1"}


def _as_user(argv: list[str]) -> list[str]:
    """``argv`` run by a user file modes apply to."""
    if os.geteuid() != 0:
        return argv
    return ["setpriv", f"--reuid={NOBODY}", f"--regid={NOBODY}", "--clear-groups", *argv]


@pytest.fixture(scope="module")
def endpoint() -> Iterator[str]:
    """A CoolPro at address 40 on Modbus TCP: HOST:PORT."""
    sim = SimulatorProcess(["coolpro:40", "--tcp", "127.0.0.1:0"], quiet=True).start()
    try:
        yield sim.endpoint
    finally:
        sim.stop()


@pytest.fixture
def place() -> Iterator[Path]:
    """A directory the unprivileged user can reach (pytest's own are root's,
    mode 0700), removed afterwards whatever its modes became."""
    if os.geteuid() == 0:
        if shutil.which("setpriv") is None:
            pytest.skip("cannot drop privileges: no setpriv (util-linux)")
        probe = subprocess.run(_as_user([*PYMB, "--version"]), capture_output=True, text=True,
                               env=ENV, timeout=60, check=False)
        if probe.returncode != 0:
            pytest.skip(f"cannot drop privileges: uid {NOBODY} cannot run pymb from this "
                        f"checkout ({probe.stderr.strip().splitlines()[-1:]})")
    top = Path(tempfile.mkdtemp(prefix="pymb-eacces-"))
    top.chmod(0o755)
    try:
        yield top
    finally:
        for p in [top, *top.rglob("*")]:
            if p.is_dir() and not p.is_symlink():
                p.chmod(0o755)
        shutil.rmtree(top)


def _mine(path: Path, mode: int) -> Path:
    """``path`` given to the unprivileged user, with ``mode``."""
    if os.geteuid() == 0:
        os.chown(path, NOBODY, NOBODY)
    path.chmod(mode)
    return path


def _log(endpoint: str, db: Path, *extra: str) -> subprocess.Popen[str]:
    return subprocess.Popen(_as_user([*PYMB, "log", "coolpro:40", "--tcp", endpoint, "--out",
                                      str(db), "--quiet", "--commit-interval", "0.5", *extra]),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV)


def _refused(proc: subprocess.Popen[str]) -> str:
    """Exit 5 and one line: EACCES, what to do, no traceback; that line."""
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 5, err
    assert "Traceback" not in err
    lines = without_events(err)
    assert len(lines) == 1, err
    assert "Permission denied (EACCES)" in lines[0], lines[0]
    assert "let the user running pymb write the file and its directory" in lines[0], lines[0]
    return lines[0]


def _ids(db: Path) -> list[int]:
    with closing(sqlite3.connect(f"file:{db}?mode=ro", uri=True)) as con:
        assert con.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
        return [i for (i,) in con.execute("SELECT id FROM samples ORDER BY id")]


def _existing(endpoint: str, where: Path) -> Path:
    """A pymb database at ``where/data.sqlite`` with a few samples (made by root)."""
    db = where / "data.sqlite"
    done = subprocess.run([*PYMB, "log", "coolpro:40", "--tcp", endpoint, "--out", str(db),
                           "--seconds", "1", "--quiet"], capture_output=True, text=True,
                          env=ENV, timeout=120, check=False)
    assert done.returncode == 0, done.stderr
    return db


@pytest.mark.parametrize("case", ["new file, directory read-only", "file read-only",
                                  "file writable, directory read-only",
                                  "directory not searchable"])
def test_refused_at_start_with_the_reason(endpoint: str, place: Path, case: str) -> None:
    where = place / "state"
    where.mkdir()
    db = where / "data.sqlite" if case.startswith("new") else _existing(endpoint, where)
    before = sorted(os.listdir(where))
    content = db.read_bytes() if db.exists() else None
    if case == "new file, directory read-only":
        _mine(where, 0o555)
    elif case == "file read-only":  # the directory the user's: room for -wal and -shm
        _mine(db, 0o444)
        _mine(where, 0o755)
    elif case == "file writable, directory read-only":  # no room for -wal and -shm
        _mine(db, 0o644)
        _mine(where, 0o555)
    else:  # root's directory (the tests' user's, without x)
        _mine(db, 0o644)
        where.chmod(0o700 if os.geteuid() == 0 else 0o600)
    _refused(_log(endpoint, db, "--seconds", "30"))
    # Nothing written, nothing left behind.
    where.chmod(0o755)
    assert sorted(os.listdir(where)) == before
    if content is not None:
        assert db.read_bytes() == content


def test_permissions_taken_away_while_logging(endpoint: str, place: Path) -> None:
    """The files stay open: the logger goes on and loses nothing; the next
    start (a service's restart) is refused with the reason; given back, a
    start resumes on the same database."""
    where = place / "state"
    where.mkdir()
    _mine(where, 0o755)
    db = where / "data.sqlite"
    proc = _log(endpoint, db)
    try:
        wait_for(db, SAMPLES, at_least=5, proc=proc)
        db.chmod(0o444)
        where.chmod(0o555)
        taken = len(_ids(db))
        # Commits go on into the open files after the modes changed.
        wait_for(db, SAMPLES, at_least=taken + 10, proc=proc)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
        assert proc.returncode == 0, err
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    kept = _ids(db)
    assert len(kept) >= taken + 10
    _refused(_log(endpoint, db, "--seconds", "30"))
    assert _ids(db) == kept
    # Given back: the same database, its ids continue.
    where.chmod(0o755)
    db.chmod(0o644)
    proc = _log(endpoint, db)
    try:
        wait_for(db, "SELECT COUNT(*) FROM samples WHERE id > ?", (kept[-1],), at_least=3,
                 proc=proc)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
        assert proc.returncode == 0, err
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    again = _ids(db)
    assert again[:len(kept)] == kept
    assert len(again) > len(kept)


@pytest.mark.parametrize("fmt", ["csv", "jsonl", "influx"])
@pytest.mark.parametrize("case", ["new file, directory read-only", "file read-only"])
def test_a_text_output_refused_at_start_exits_5_as_sqlite(endpoint: str, place: Path, fmt: str,
                                                           case: str) -> None:
    where = place / "out"
    where.mkdir()
    out = where / f"data.{fmt}"
    if case == "file read-only":
        out.write_text("")
        _mine(out, 0o444)
        _mine(where, 0o755)
    else:
        _mine(where, 0o555)
    line = _refused(_log(endpoint, out, "--format", fmt, "--seconds", "30"))
    assert str(out) in line
    where.chmod(0o755)
    assert out.exists() == (case == "file read-only")
    if out.exists():
        assert out.read_bytes() == b""
