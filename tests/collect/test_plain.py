"""``pymb collect`` of the plain profile into SQLite, end to end: a real
mosquitto, ``pymb log --mqtt`` on a simulated CoolPro, an independent paho
subscriber; the stored rows compared with what it saw, value by value, through
a SIGKILL of the collector, a broker restart, messages published twice and bad
input."""

from __future__ import annotations

import json
import signal

import pytest

pytest.register_assert_rewrite("mqtt_broker", "collectkit")
from collectkit import (  # noqa: E402
    Collectors,
    all_received,
    expected_plain,
    publish,
    same_facts,
    sqlite_count,
    sqlite_facts,
    stop,
    wait_rows,
    wait_subscribed,
)
from conftest import wait_until  # noqa: E402
from mqtt_broker import Fleet, db_count, plain_ids, stop_log  # noqa: E402

pytest_plugins = ["mqtt_broker", "collectkit"]


def test_sigkill_and_broker_restart_lose_nothing_and_store_nothing_twice(
        fleet: Fleet, collectors: Collectors) -> None:
    broker = fleet.broker()
    sim = fleet.simulator("coolpro")
    sub = fleet.subscribe(broker, "pymb/+/+")
    out = fleet.tmp / "fleet.sqlite"
    col = collectors.start(broker.url, str(out), "--client-id", "c1")
    wait_subscribed(col)
    log_db = fleet.tmp / "board.sqlite"
    log = fleet.log(sim.endpoint, log_db, "--mqtt", broker.url, "--mqtt-node", "gw1")
    wait_rows(lambda: sqlite_count(out), 1000, "rows before the kill")
    col.send_signal(signal.SIGKILL)
    col.communicate(timeout=30)
    before = db_count(log_db)
    wait_until(lambda: db_count(log_db) >= before + 100, "100 samples while it is dead", 30)
    col = collectors.start(broker.url, str(out), "--client-id", "c1")
    wait_subscribed(col)
    wait_rows(lambda: sqlite_count(out), sqlite_count(out) + 500, "rows after the restart")
    broker.stop()
    before = db_count(log_db)
    wait_until(lambda: db_count(log_db) >= before + 100, "100 samples while the broker is down",
               30)
    broker.start()
    wait_until(lambda: max(plain_ids(sub.snapshot())) > before + 100,
               "live samples after the broker's restart", 60)
    stop_log(log)
    messages = all_received(sub, log_db)
    expected = expected_plain(messages)
    wait_rows(lambda: sqlite_count(out), len(expected), "every value stored")
    err = stop(col)
    same_facts(sqlite_facts(out), expected)
    assert "0 bad" in err, err


def test_the_same_samples_twice_are_stored_once(fleet: Fleet, collectors: Collectors) -> None:
    broker = fleet.broker()
    sim = fleet.simulator("coolpro")
    sub = fleet.subscribe(broker, "pymb/+/+")
    out = fleet.tmp / "fleet.sqlite"
    col = collectors.start(broker.url, str(out), "--client-id", "c2")
    wait_subscribed(col)
    log_db = fleet.tmp / "board.sqlite"
    log = fleet.log(sim.endpoint, log_db, "--mqtt", broker.url, "--mqtt-node", "gw2",
                    seconds=2)
    _, log_err = log.communicate(timeout=60)
    assert log.returncode == 0, log_err
    messages = all_received(sub, log_db)
    expected = expected_plain(messages)
    wait_rows(lambda: sqlite_count(out), len(expected), "every value stored")
    data = [(t, p) for t, p in messages if not t.endswith("/status")]
    # a board's backlog sent again, then one new sample: once its row is stored,
    # the collector (one writer, batches in order) has handled every copy
    last = {"time_utc": 1900000000.0, "sample": 10**9, "values": {"v": 1.0}}
    publish(broker.port, [*data, ("pymb/gw2/last", json.dumps(last).encode())])
    wait_rows(lambda: sqlite_count(out), len(expected) + 1, "the sample after the copies")
    err = stop(col)
    expected.add(("gw2", "last", "v", 1900000000.0, 1.0, None, None, 10**9))
    same_facts(sqlite_facts(out), expected)
    assert f"{len(expected) - 1:,} already stored" in err, err


def test_bad_input_is_counted_reported_and_never_blocks(
        fleet: Fleet, collectors: Collectors) -> None:
    broker = fleet.broker()
    out = fleet.tmp / "fleet.sqlite"
    col = collectors.start(broker.url, str(out), "--client-id", "c3")
    wait_subscribed(col)
    good = {"time_utc": 1800000000.5, "sample": 7, "values": {"v": 1.5, "flag": True,
            "name": "pump", "block": [1, None, 3]},
            "states": {"block": [None, "offline", None]}}
    publish(broker.port, [
        ("pymb/gw/notjson", b"\xff{not json"),
        ("pymb/gw/wrongtype", json.dumps({"time_utc": 1.0, "values": {"v": {"a": 1}}}).encode()),
        ("pymb/gw/notime", json.dumps({"values": {"v": 1}}).encode()),
        ("pymb/gw/status", b"online"),
        ("pymb/gw/dev", json.dumps(good).encode()),
    ])
    wait_rows(lambda: sqlite_count(out), 6, "the good message's rows behind the bad ones")
    err = stop(col)
    for topic in ("pymb/gw/notjson", "pymb/gw/wrongtype", "pymb/gw/notime"):
        assert f"bad input on {topic}:" in err, err
    assert "3 bad" in err
    assert "status" not in err.replace("subscribed", "")
    assert sorted(sqlite_facts(out)) == [
        ("gw", "dev", "block_1", 1800000000.5, 1.0, None, None, 7),
        ("gw", "dev", "block_2", 1800000000.5, None, None, "offline", 7),
        ("gw", "dev", "block_3", 1800000000.5, 3.0, None, None, 7),
        ("gw", "dev", "flag", 1800000000.5, 1.0, None, None, 7),
        ("gw", "dev", "name", 1800000000.5, None, "pump", None, 7),
        ("gw", "dev", "v", 1800000000.5, 1.5, None, None, 7),
    ]
