"""One writer per database: a second writer is refused at once, naming the
first; the first loses nothing; readers never disturb it.

Real processes: ``pymb log`` children against a simulated CoolPro on
Modbus TCP (its own process), a second ``pymb log`` started at many moments
of the first one's life (before its file exists, as it is made, while it
writes), ``pymb export`` and the ``sqlite3`` shell reading meanwhile.
"""

from __future__ import annotations

import re
import shutil
import signal
import sqlite3
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import PYMB, PYMB_ENV, run_pymb, wait_until
from dbwait import count, wait_for
from docblocks import claim_one

from pymb.sim import SimulatorProcess
from pymb.store import SqliteSink
from pymb.store.lock import DatabaseInUse

SAMPLES = "SELECT COUNT(*) FROM samples"


@pytest.fixture
def coolpro() -> Iterator[str]:
    """A simulated CoolPro on Modbus TCP in its own process: HOST:PORT."""
    sim = SimulatorProcess(["coolpro", "--tcp", "127.0.0.1:0"], quiet=True).start()
    try:
        yield sim.endpoint
    finally:
        sim.stop()


def _log(endpoint: str, db: Path, *extra: str) -> subprocess.Popen[str]:
    # Commits five times a second: the test waits on what is committed.
    return subprocess.Popen([*PYMB, "log", "coolpro:40", "--tcp", endpoint, "--out", str(db),
                             "--commit-interval", "0.2", *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=PYMB_ENV)


def _logged(stderr: str) -> int:
    m = re.search(r"logged ([\d,]+) samples", stderr)
    assert m, stderr
    return int(m.group(1).replace(",", ""))


def _refused(proc: subprocess.Popen[str], holder: int) -> None:
    """``proc`` was refused: exit 2 and one line naming the holder."""
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert re.fullmatch(rf"pymb log: .*data\.sqlite is being written by pymb log, PID {holder}"
                        r"; stop it first or log to another file", lines[0]), lines[0]
    # docs/reliability.md shows this line, for data.sqlite in the current folder
    shown = claim_one("docs/reliability.md", "text", how="compare",
                      contains="is being written by").text.strip()
    real = re.sub(r"\S*data\.sqlite", "data.sqlite", lines[0].replace(f"PID {holder}", "PID 1234"))
    assert real == shown, (real, shown)


def _stop(proc: subprocess.Popen[str], db: Path) -> None:
    """SIGTERM the first logger: it ends cleanly and its file holds all it logged."""
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    assert _logged(err) == count(db, SAMPLES) > 0
    assert count(db, "SELECT COUNT(*) FROM events WHERE kind NOT IN ('connect')") == 0


def test_a_second_writer_is_refused_at_every_moment(coolpro: str, tmp_path: Path) -> None:
    db = tmp_path / "data.sqlite"
    first = _log(coolpro, db)
    try:
        wait_until(db.exists, "the first logger's database", 60,
                   alive=lambda: first.poll() is None)
        for rows in (0, 1, 50, 300, 1000):
            wait_for(db, SAMPLES, at_least=rows, proc=first)
            _refused(_log(coolpro, db, "--seconds", "5"), first.pid)
        _stop(first, db)
    finally:
        if first.poll() is None:
            first.kill()
            first.communicate()


@pytest.mark.parametrize("stagger", range(4))
def test_two_writers_started_together(coolpro: str, tmp_path: Path, stagger: int) -> None:
    """Started at once (the file made by both, or by one while the other
    looks): one logs, the other is refused, whichever wins."""
    db = tmp_path / "data.sqlite"
    a = _log(coolpro, db)
    b = _log(coolpro, db) if stagger % 2 == 0 else None
    try:
        if b is None:
            wait_until(lambda: db.exists() or a.poll() is not None, "the file", 60)
            b = _log(coolpro, db)
        wait_until(lambda: a.poll() is not None or b.poll() is not None, "a refusal", 60)
        winner, loser = (a, b) if b.poll() is not None else (b, a)
        _refused(loser, winner.pid)
        wait_for(db, SAMPLES, at_least=20, proc=winner)
        _stop(winner, db)
    finally:
        for p in (a, b):
            if p is not None and p.poll() is None:
                p.kill()
                p.communicate()


def test_readers_never_disturb_the_writer(coolpro: str, tmp_path: Path) -> None:
    db = tmp_path / "data.sqlite"
    first = _log(coolpro, db)
    try:
        wait_for(db, SAMPLES, at_least=1, proc=first)
        shell = shutil.which("sqlite3")
        for i in range(6):
            done = run_pymb("export", str(db), "--csv", str(tmp_path / f"x{i}.csv"))
            assert done.returncode == 0, done.stderr
            if shell:
                q = subprocess.run([shell, str(db), SAMPLES + ";"], capture_output=True,
                                   text=True, timeout=60, check=False)
                assert q.returncode == 0, q.stderr
                assert int(q.stdout) > 0
            # A reader that holds its snapshot while the writer commits on.
            with sqlite3.connect(db) as con:
                con.execute("BEGIN")
                seen = con.execute(SAMPLES).fetchone()[0]
                wait_for(db, SAMPLES, at_least=seen + 100, proc=first)
                assert con.execute(SAMPLES).fetchone()[0] == seen
                con.execute("COMMIT")
        _stop(first, db)
    finally:
        if first.poll() is None:
            first.kill()
            first.communicate()


def test_in_one_process_too(tmp_path: Path) -> None:
    """The library refuses a second SqliteSink on a file this process writes,
    and lets the next one in once the first is closed."""
    db = tmp_path / "data.sqlite"
    first = SqliteSink(db)
    with pytest.raises(DatabaseInUse, match=r"is being written by .*PID \d+"):
        SqliteSink(db)
    first.close()
    SqliteSink(db).close()
