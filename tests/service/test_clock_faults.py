"""Clock faults a board meets, beside tests/service/test_clock.py: a set
clock that steps back to 1970 (a lost real-time clock), a plausible but
wrong boot date, and a step after a long run.

A step never moves a correct time into an earlier epoch, never deletes an
unsent sample by an age computed from a wrong clock, and re-stamps a long
run in bounded steps (bounded work and WAL per commit), never in one
transaction. The wall clock of a ``pymb log`` process is Debian's
libfaketime (``FAKETIME_TIMESTAMP_FILE`` re-read at every call, the
monotonic clock left real).
"""

from __future__ import annotations

import signal
import socket
import sqlite3
import subprocess
import time
from array import array
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

pytest.register_assert_rewrite("servicekit")
from conftest import PYMB, run_pymb, wait_until  # noqa: E402
from servicekit import StderrLines, faketime_env, set_clock  # noqa: E402

from pymb.devices import decode_hub  # noqa: E402
from pymb.sim import SimulatorProcess  # noqa: E402
from pymb.store import DeviceInfo, Sample, SqliteSink  # noqa: E402
from pymb.store.retention import PLAUSIBLE  # noqa: E402


@pytest.fixture
def coolpro() -> Iterator[str]:
    """A simulated CoolPro on Modbus TCP in its own process: HOST:PORT."""
    sim = SimulatorProcess(["coolpro:40", "--tcp", "127.0.0.1:0"], quiet=True).start()
    try:
        yield sim.endpoint
    finally:
        sim.stop()


def _rows(db: Path, sql: str, *args: object) -> list[tuple[Any, ...]]:
    if not db.exists():
        return []
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=10)
    try:
        return con.execute(sql, args).fetchall()
    except sqlite3.OperationalError:  # the schema not made yet
        return []
    finally:
        con.close()


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_a_set_clock_that_steps_back_to_1970_moves_no_time_into_1970(
        coolpro: str, tmp_path: Path) -> None:
    db, clock = tmp_path / "board.sqlite", tmp_path / "faketime.rc"
    proc = subprocess.Popen([*PYMB, "log", "--tcp", coolpro, "coolpro:40", "--interval", "0.05",
                             "--out", str(db), "--commit-interval", "0.5"],
                            stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True,
                            env=faketime_env(clock, "+0"), start_new_session=True)
    err = StderrLines(proc)
    try:
        wait_until(lambda: (_rows(db, "SELECT COUNT(*) FROM samples") or [(0,)])[0][0] >= 20,
                   "20 samples committed", 30, alive=lambda: proc.poll() is None)
        set_at = time.time()
        set_clock(clock, "@1970-01-02 00:00:00")  # the real-time clock lost
        wait_until(lambda: _rows(db, "SELECT 1 FROM events WHERE kind = 'clock'"),
                   "the clock event", 30, alive=lambda: proc.poll() is None)
        (top,), = _rows(db, "SELECT MAX(id) FROM samples")
        wait_until(lambda: _rows(db, "SELECT COUNT(*) FROM samples WHERE id > ?", top)[0][0]
                   >= 40, "40 samples after the step", 30, alive=lambda: proc.poll() is None)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(60) == 0, err.text()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert _rows(db, "SELECT COUNT(*) FROM samples WHERE time_utc < ?", PLAUSIBLE) == [(0,)]
    assert _rows(db, "SELECT COUNT(*) FROM events WHERE time_utc < ?", PLAUSIBLE) == [(0,)]
    (message,), = _rows(db, "SELECT message FROM events WHERE kind = 'clock'")
    assert "cannot be the real one" in message
    # the samples after the step have the time of the set clock, running on
    (newest,), = _rows(db, "SELECT MAX(time_utc) FROM samples")
    assert set_at < newest < time.time() + 1
    assert _rows(db, "SELECT COUNT(*) FROM samples a JOIN samples b ON b.id = a.id + 1 "
                     "WHERE b.time_utc < a.time_utc") == [(0,)]


def test_a_wrong_boot_date_loses_no_unsent_sample_by_age(coolpro: str, tmp_path: Path) -> None:
    """A board boots at a plausible but wrong date (a saved clock, 2025-06-01)
    and logs with a broker not reachable yet; the next start has the right
    clock and an age limit of a day: the samples stamped in 2025 look a year
    old, but none was sent: every one stays."""
    db, clock = tmp_path / "board.sqlite", tmp_path / "faketime.rc"
    mqtt = ["--mqtt", f"mqtt://127.0.0.1:{_closed_port()}", "--mqtt-node", "gw-date"]
    r = run_pymb("log", "--tcp", coolpro, "coolpro:40", "--interval", "0.05", "--seconds", "2",
                 "--out", str(db), "--quiet", *mqtt,
                 env=faketime_env(clock, "@2025-06-01 12:00:00"))
    assert r.returncode == 0, r.stderr
    wrong = {i for (i,) in _rows(db, "SELECT id FROM samples")}
    assert wrong
    assert _rows(db, "SELECT COUNT(*) FROM samples WHERE time_utc > ?", PLAUSIBLE + 3e7) == \
        [(0,)]  # stamped in 2025
    proc = subprocess.Popen([*PYMB, "log", "--tcp", coolpro, "coolpro:40", "--interval", "0.05",
                             "--out", str(db), "--max-age-days", "1", *mqtt,
                             "--commit-interval", "0.5"],  # whatever the default, it trims
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            env=faketime_env(clock, "+0"), start_new_session=True)
    err = StderrLines(proc)
    try:
        # the age limit is looked at every 5 s: 7 s of samples of this run
        def span() -> float:
            got = _rows(db, "SELECT MAX(monotonic) - MIN(monotonic) FROM samples WHERE id > ?",
                        max(wrong))
            return float(got[0][0] or 0) if got else 0.0

        wait_until(lambda: span() >= 7, "7 s of samples", 60, alive=lambda: proc.poll() is None)
        time.sleep(0.5)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(60) == 0, err.text()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    kept = {i for (i,) in _rows(db, "SELECT id FROM samples")}
    assert wrong <= kept, f"{len(wrong - kept)} unsent samples deleted by age"


def test_a_step_restamps_a_long_run_in_bounded_steps(tmp_path: Path) -> None:
    """A +5 s step after 6,000 hub sweeps (8 MB) stored with the old clock:
    the run is re-stamped a bounded number of rows per commit, the WAL after
    each commit within its budget, far below the run's size (it was one
    transaction of all of it, the WAL as large as the file)."""
    db = tmp_path / "long.sqlite"
    sink = SqliteSink(db, max_bytes=40_000_000)  # a WAL budget of 2.5 MB
    hub = DeviceInfo("b", "p", "hub", 1, "hub-1")
    reading = decode_hub(array("H", range(700)))
    t0 = 1.8e9
    for i in range(6000):
        sink.write(Sample(hub, t0 + i, float(i), reading))
        if i % 100 == 99:
            sink.commit()
    sink.commit()
    size = db.stat().st_size
    assert size > 8_000_000
    wal = Path(f"{db}-wal")
    sink.restamp(t0 + 5.0)  # the clock was 5 s behind
    steps, worst = 0, 0
    while sink.restamping and steps < 1000:
        sink.write(Sample(hub, t0 + 5.0 + 6000 + steps, 6000.0 + steps, reading))
        sink.commit()
        steps += 1
        worst = max(worst, wal.stat().st_size)
    sink.close()
    assert 4 <= steps < 1000, steps
    assert worst <= sink.wal_budget, (worst, sink.wal_budget, size)
    con = sqlite3.connect(db)
    try:
        wrong = con.execute("SELECT COUNT(*) FROM samples WHERE ABS(time_utc - monotonic - ?) "
                            "> 0.001", (t0 + 5.0,)).fetchone()[0]
    finally:
        con.close()
    assert wrong == 0
