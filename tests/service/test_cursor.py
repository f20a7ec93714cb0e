"""The outbox cursor is keyed by the receiver (the broker's address as
resolved, port, profile, node), not by the URL's spelling; --mqtt-start
chooses where a new cursor starts; a new cursor that would send more than a
day of samples says so. Against Debian's mosquitto (tests/mqtt_broker.py)."""

from __future__ import annotations

import socket
import sqlite3
from pathlib import Path

import pytest

pytest.register_assert_rewrite("mqtt_broker")
from conftest import run_pymb, wait_until  # noqa: E402
from mqtt_broker import Fleet, db_count, db_ids, duplicates, plain_ids, stop_log  # noqa: E402

pytest_plugins = ["mqtt_broker"]  # the fixtures: fleet, simulator, ...
NODE = "gw-cursor"


def _outbox(db: Path) -> dict[str, int]:
    con = sqlite3.connect(db)
    try:
        return dict(con.execute("SELECT name, sample_id FROM outbox").fetchall())
    finally:
        con.close()


def _localhost_is_loopback() -> bool:
    try:
        return "127.0.0.1" in {a[4][0] for a in socket.getaddrinfo("localhost", 1883)}
    except OSError:
        return False


def test_another_spelling_of_the_broker_replays_nothing(fleet: Fleet, simulator: str,
                                                        tmp_path: Path) -> None:
    if not _localhost_is_loopback():
        pytest.skip("localhost does not resolve to 127.0.0.1 here")
    broker = fleet.broker()
    sub = fleet.subscribe(broker, f"pymb/{NODE}/#")
    db = tmp_path / "log.sqlite"
    first = fleet.log(simulator, db, "--mqtt", f"mqtt://127.0.0.1:{broker.port}",
                      "--mqtt-node", NODE)
    wait_until(lambda: len(plain_ids(sub.snapshot())) >= 30, "30 samples live", 30)
    stop_log(first)
    sent = set(plain_ids(sub.snapshot()))
    assert sent == db_ids(db)
    key = f"mqtt://127.0.0.1:{broker.port}/plain/{NODE}"
    assert _outbox(db) == {key: max(sent)}
    second = fleet.log(simulator, db, "--mqtt", f"mqtt://localhost:{broker.port}",
                       "--mqtt-node", NODE)
    wait_until(lambda: len(plain_ids(sub.snapshot())) >= len(sent) + 30,
               "30 more samples", 30)
    stop_log(second)
    got = plain_ids(sub.snapshot())
    assert duplicates(got) == 0  # nothing of the first run sent again
    assert set(got) == db_ids(db)
    assert _outbox(db) == {key: max(got)}  # the same cursor, one row


def test_a_cursor_keyed_by_an_older_pymb_is_taken_over(fleet: Fleet, simulator: str,
                                                       tmp_path: Path) -> None:
    broker = fleet.broker()
    db = tmp_path / "log.sqlite"
    r = run_pymb("log", "--tcp", simulator, "coolpro:40", "--interval", "0.01",
                 "--seconds", "1", "--out", str(db), "--quiet")
    assert r.returncode == 0, r.stderr
    before = db_ids(db)
    con = sqlite3.connect(db)  # the URL-text key of an older pymb, everything sent
    con.execute("CREATE TABLE IF NOT EXISTS outbox(name TEXT PRIMARY KEY, "
                "sample_id INTEGER NOT NULL)")
    con.execute("INSERT INTO outbox VALUES (?, ?)",
                (f"mqtt://LocalHost.:{broker.port}/plain/{NODE}".lower().replace(".:", ":"),
                 max(before)))
    con.commit()
    con.close()
    sub = fleet.subscribe(broker, f"pymb/{NODE}/#")
    proc = fleet.log(simulator, db, "--mqtt", f"mqtt://localhost:{broker.port}",
                     "--mqtt-node", NODE)
    wait_until(lambda: len(plain_ids(sub.snapshot())) >= 20, "20 new samples", 30)
    stop_log(proc)
    got = plain_ids(sub.snapshot())
    assert min(got) > max(before)  # the old samples were sent under the old key
    out = _outbox(db)
    assert list(out) in ([f"mqtt://127.0.0.1:{broker.port}/plain/{NODE}"],
                         [f"mqtt://[::1]:{broker.port}/plain/{NODE}"])


@pytest.mark.parametrize("start", ["oldest", "now"])
def test_mqtt_start_chooses_where_a_new_cursor_starts(fleet: Fleet, simulator: str,
                                                      tmp_path: Path, start: str) -> None:
    db = tmp_path / "log.sqlite"
    r = run_pymb("log", "--tcp", simulator, "coolpro:40", "--interval", "0.01",
                 "--seconds", "1", "--out", str(db), "--quiet")
    assert r.returncode == 0, r.stderr
    before = db_ids(db)
    assert len(before) >= 10
    con = sqlite3.connect(db)  # two days old: a new cursor at the oldest says so
    con.execute("UPDATE samples SET time_utc = time_utc - 2 * 86400")
    con.commit()
    con.close()
    broker = fleet.broker()
    sub = fleet.subscribe(broker, f"pymb/{NODE}/#")
    proc = fleet.log(simulator, db, "--mqtt", broker.url, "--mqtt-node", NODE,
                     "--mqtt-start", start)
    wait_until(lambda: db_count(db) >= len(before) + 20, "20 new samples", 30)
    wait_until(lambda: set(plain_ids(sub.snapshot())) >= db_ids(db) - before,
               "the new samples at the subscriber", 30)
    err = stop_log(proc)
    got = set(plain_ids(sub.snapshot()))
    notice = [line for line in err.splitlines() if "new MQTT cursor" in line]
    if start == "oldest":
        assert got == db_ids(db)
        assert len(notice) == 1, err
        n = int(notice[0].split("oldest sample: ")[1].split(" samples")[0].replace(",", ""))
        assert n >= len(before)
        assert "(2.0 days) are sent" in notice[0]
        assert notice[0].endswith("--mqtt-start now sends only new ones")
    else:
        assert got == db_ids(db) - before
        assert notice == [], err
