"""Steps of the wall clock under a running logger, made by Debian's
libfaketime (``FAKETIME_TIMESTAMP_FILE`` re-read at every call, the
monotonic clock left real): a board that boots in 1970 and is stepped to
the present, and a step back. Nothing is lost by age before the clock is
set or before it is forwarded, what the run stored is re-stamped (time order
is id order again), a step is an event, and the forwarder's rate stays
sane."""

from __future__ import annotations

import os
import re
import signal
import sqlite3
import subprocess
import time
from pathlib import Path
from typing import Any

import pytest

pytest.register_assert_rewrite("mqtt_broker", "servicekit")
from conftest import PYMB, run_pymb, wait_until  # noqa: E402
from mqtt_broker import Fleet, db_ids, plain_ids  # noqa: E402
from servicekit import NotifyListener, StderrLines, faketime_env, set_clock  # noqa: E402

from pymb.store.retention import PLAUSIBLE  # noqa: E402

pytest_plugins = ["mqtt_broker"]  # the fixtures: fleet, simulator, ...
NODE = "gw-clock"


def _rows(db: Path, sql: str, *args: object) -> list[tuple[Any, ...]]:
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=10)
    try:
        return con.execute(sql, args).fetchall()
    finally:
        con.close()


def _ids(db: Path, where: str, *args: object) -> set[int]:
    return {int(i) for (i,) in _rows(db, f"SELECT id FROM samples WHERE {where}", *args)}


def _time_order_is_id_order(db: Path) -> bool:
    ids = [i for (i,) in _rows(db, "SELECT id FROM samples WHERE time_utc >= ? "
                                   "ORDER BY time_utc, id", PLAUSIBLE)]
    return ids == sorted(ids)


def _log(sim: str, db: Path, env: dict[str, str], *more: str) -> subprocess.Popen[str]:
    return subprocess.Popen([*PYMB, "log", "--tcp", sim, "coolpro:40", "--interval", "0.02",
                             "--commit-interval", "0.5",  # the test watches the rows
                             "--out", str(db), *more], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True, env=env,
                            start_new_session=True)


def test_a_board_that_boots_in_1970(fleet: Fleet, simulator: str, tmp_path: Path) -> None:
    db, clock = tmp_path / "board.sqlite", tmp_path / "faketime.rc"
    # the previous boots: three days ago (clock set), then one in 1970 (clock never set)
    for spec in ("-259200", "@1970-01-02 00:00:00"):
        r = run_pymb("log", "--tcp", simulator, "coolpro:40", "--interval", "0.05",
                     "--seconds", "1", "--out", str(db), "--quiet", env=faketime_env(clock, spec))
        assert r.returncode == 0, r.stderr
    old = _ids(db, "time_utc >= ?", PLAUSIBLE)  # three days old: past --max-age-days 1
    unset = _ids(db, "time_utc < ?", PLAUSIBLE)  # 1970: age unknown
    assert old
    assert unset
    broker = fleet.broker()
    sub = fleet.subscribe(broker, f"pymb/{NODE}/#")
    broker.stop()  # the network comes later than the logger
    proc = _log(simulator, db, faketime_env(clock, "@1970-01-02 00:00:00"), "--max-age-days", "1",
                "--mqtt", broker.url, "--mqtt-node", NODE)
    err = StderrLines(proc)
    try:
        # long enough for the age limit to have been looked at (every 5 s) in 1970
        wait_until(lambda: (_rows(db, "SELECT MAX(monotonic) - MIN(monotonic) FROM samples "
                                      "WHERE id > ?", max(unset))[0][0] or 0) >= 6,
                   "6 s of samples in 1970", 30, alive=lambda: proc.poll() is None)
        assert _ids(db, "id <= ?", max(unset)) == old | unset  # nothing deleted by age
        before = _ids(db, "id > ?", max(unset))
        assert all(t < PLAUSIBLE for (t,) in _rows(db, "SELECT time_utc FROM samples "
                                                       "WHERE id > ?", max(unset)))
        set_clock(clock, "+0")  # NTP: the present
        # The step forward is the event looked for; libfaketime re-reading its
        # file under load can first show a step back of a second or two in 1970.
        forward = "SELECT message FROM events WHERE kind = 'clock' AND message LIKE " \
                  "'the clock stepped forward by%'"
        wait_until(lambda: _rows(db, forward), "the clock event", 30,
                   alive=lambda: proc.poll() is None)
        (message,), = _rows(db, forward)
        assert "the clock stepped forward by" in message
        assert "(the clock had not been set)" in message
        err.wait_for("pymb log: clock clock: the clock stepped forward")  # in the journal
        # this run's samples are re-stamped (in bounded steps: wait for the last)
        wait_until(lambda: not _ids(db, "id > ? AND time_utc < ?", max(unset), PLAUSIBLE),
                   "this run's samples re-stamped", 30, alive=lambda: proc.poll() is None)
        # the age limit runs with the clock set (every 5 s); the samples three
        # days old and those of 1970 stay: none was sent yet
        time.sleep(6.0)
        assert _ids(db, "id <= ?", max(unset)) == old | unset
        assert _ids(db, "id > ? AND time_utc < ?", max(unset), PLAUSIBLE) == set()
        assert before <= _ids(db, "id > ?", max(unset))
        assert _time_order_is_id_order(db)  # "the value at time t" finds the right row
        offsets = _rows(db, "SELECT MAX(time_utc - monotonic) - MIN(time_utc - monotonic) "
                            "FROM samples WHERE id > ?", max(unset))[0][0]
        assert offsets < 1.0  # one clock for the whole run
        # the broker comes: everything is sent, then the old and the 1970 samples
        # may go by age
        broker.start()
        wait_until(lambda: set(plain_ids(sub.snapshot())) >= old | unset | before,
                   "the old samples at the subscriber", 60, alive=lambda: proc.poll() is None)
        wait_until(lambda: not _ids(db, "id <= ?", max(unset)), "the old and the 1970 "
                   "samples trimmed once forwarded", 30, alive=lambda: proc.poll() is None)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(60) == 0, err.text()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    left = db_ids(db)  # the stop's drain sent them; the last may still be on their way
    wait_until(lambda: set(plain_ids(sub.snapshot())) >= left,
               lambda: f"{len(left - set(plain_ids(sub.snapshot())))} samples to arrive", 30)


def test_a_step_back(fleet: Fleet, simulator: str, tmp_path: Path) -> None:
    db, clock = tmp_path / "back.sqlite", tmp_path / "faketime.rc"
    broker = fleet.broker()
    sub = fleet.subscribe(broker, f"pymb/{NODE}/#")
    name = f"@pymb-test-clock-{os.getpid()}"
    listener = NotifyListener(name)
    env = {**faketime_env(clock, "+0"), "NOTIFY_SOCKET": name}
    proc = _log(simulator, db, env, "--mqtt", broker.url, "--mqtt-node", NODE, "--quiet")
    err = StderrLines(proc)
    try:
        wait_until(lambda: len(plain_ids(sub.snapshot())) >= 50, "50 samples forwarded", 30,
                   alive=lambda: proc.poll() is None)
        stepped_at = time.monotonic()
        set_clock(clock, "-3600")  # an operator sets the clock back an hour
        wait_until(lambda: _rows(db, "SELECT message FROM events WHERE kind = 'clock'"),
                   "the clock event", 30, alive=lambda: proc.poll() is None)
        # the first clock event is the step; libfaketime re-reads its file per
        # thread, so a thread can stamp with the old offset a moment longer and
        # a second, spurious step be seen (no real clock does that)
        message = _rows(db, "SELECT message FROM events WHERE kind = 'clock' ORDER BY id")[0][0]
        assert "the clock stepped back by 3,600" in message

        def rate_after_step() -> list[float]:
            # STATUS= every 5 s; the forwarder's rate from a status sent 6 s after the step
            if time.monotonic() - stepped_at < 6:
                return []
            got = [float(m.group(1).replace(",", "")) for line in listener.lines()[-3:]
                   if (m := re.search(r"mqtt ok ([\d,.]+)/s", line))]
            return got

        rates = wait_until(rate_after_step, "a STATUS with the forwarder's rate", 30,
                           alive=lambda: proc.poll() is None)
        # 50 samples/s are logged; a rate kept over a head in the future grows past it
        assert rates[-1] < 120
        assert _time_order_is_id_order(db)  # re-stamped: nothing "in the future"
        latest = _rows(db, "SELECT MAX(time_utc) FROM samples")[0][0]
        assert latest < time.time() - 3000  # the child's clock is an hour behind
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(60) == 0, err.text()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        listener.close()
    assert set(plain_ids(sub.snapshot())) == db_ids(db)
