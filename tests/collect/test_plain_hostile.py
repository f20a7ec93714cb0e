"""``pymb collect`` (plain profile) against publishers that send out of order,
retain their samples, send very large samples, and two collectors sharing the
stream into one SQLite file: a real mosquitto, the stored rows and
``pymb_latest`` read back with sqlite3."""

from __future__ import annotations

import json
import sqlite3

import pytest

pytest.register_assert_rewrite("mqtt_broker", "collectkit")
from collectkit import (  # noqa: E402
    Collectors,
    publish,
    sqlite_count,
    sqlite_facts,
    stop,
    wait_rows,
    wait_subscribed,
)
from mqtt_broker import Fleet  # noqa: E402

pytest_plugins = ["mqtt_broker", "collectkit"]

T = 1800000000.0


def _sample(t: float, n: int, **values: object) -> bytes:
    return json.dumps({"time_utc": t, "sample": n, "values": values}).encode()


def test_out_of_order_samples_and_the_latest_view(fleet: Fleet, collectors: Collectors) -> None:
    """Samples arrive newest first: every one is stored, and ``pymb_latest``
    gives the newest by time, not by arrival."""
    broker = fleet.broker()
    out = fleet.tmp / "fleet.sqlite"
    col = collectors.start(broker.url, str(out), "--client-id", "ooo")
    wait_subscribed(col)
    publish(broker.port, [("pymb/gw/dev", _sample(T + k, k, v=float(k), name=f"s{k}"))
                          for k in (5, 1, 4, 2, 3)])
    wait_rows(lambda: sqlite_count(out), 10, "every value")
    stop(col)
    con = sqlite3.connect(f"file:{out}?mode=ro", uri=True)
    try:
        latest = sorted(con.execute(
            "SELECT node, device, point, time, value, text, sample FROM pymb_latest"))
    finally:
        con.close()
    assert latest == [("gw", "dev", "name", T + 5, None, "s5", 5),
                      ("gw", "dev", "v", T + 5, 5.0, None, 5)]


def test_retained_samples_are_stored_once_across_restarts(
        fleet: Fleet, collectors: Collectors) -> None:
    """A board's retained sample is delivered again at every subscription: it is
    stored once."""
    broker = fleet.broker()
    out = fleet.tmp / "fleet.sqlite"
    publish(broker.port, [("pymb/gw/dev", _sample(T, 1, v=1.0))], retain=True)
    for k in range(3):
        col = collectors.start(broker.url, str(out), "--client-id", f"ret-{k}")
        wait_subscribed(col)
        publish(broker.port, [(f"pymb/gw/mark{k}", _sample(T, 1, v=1.0))])
        wait_rows(lambda: sqlite_count(out), 2 + k, "the mark after the retained sample")
        stop(col)
    assert sorted(f[:5] for f in sqlite_facts(out)) == [
        ("gw", "dev", "v", T, 1.0), ("gw", "mark0", "v", T, 1.0),
        ("gw", "mark1", "v", T, 1.0), ("gw", "mark2", "v", T, 1.0)]


def test_a_very_large_sample_is_stored_whole(fleet: Fleet, collectors: Collectors) -> None:
    """One message of 100,000 values (a block of 100,000 channels, about 1 MB)."""
    broker = fleet.broker()
    out = fleet.tmp / "fleet.sqlite"
    col = collectors.start(broker.url, str(out), "--client-id", "huge")
    wait_subscribed(col)
    block = [k / 8 for k in range(100000)]
    publish(broker.port, [("pymb/gw/hub", _sample(T, 9, temp=block))])
    wait_rows(lambda: sqlite_count(out), 100000, "every channel", timeout=120)
    err = stop(col)
    assert "0 bad" in err, err
    con = sqlite3.connect(f"file:{out}?mode=ro", uri=True)
    try:
        got = dict(con.execute("SELECT point, value FROM pymb_values"))
    finally:
        con.close()
    assert got == {f"temp_{k + 1}": v for k, v in enumerate(block)}


def test_two_collectors_share_the_stream_into_one_sqlite_file(
        fleet: Fleet, collectors: Collectors) -> None:
    """``--share`` into one SQLite file: the file has one writer at a time, the
    other waits its turn; together they store every sample once."""
    broker = fleet.broker()
    out = fleet.tmp / "fleet.sqlite"
    cols = [collectors.start(broker.url, str(out), "--share", "plant", "--client-id", f"sq{i}")
            for i in range(2)]
    for c in cols:
        wait_subscribed(c)
    messages = [(f"pymb/gw{k % 7}/dev", _sample(T + k, k, a=float(k), b=k % 2 == 0))
                for k in range(3000)]
    publish(broker.port, messages)
    wait_rows(lambda: sqlite_count(out), 6000, "every value", timeout=120)
    errs = [stop(c) for c in cols]
    facts = sqlite_facts(out)
    assert len(facts) == len(set(facts)) == 6000
    assert {(f[0], f[2], f[3], f[4]) for f in facts} == {
        (f"gw{k % 7}", p, T + k, v) for k in range(3000)
        for p, v in (("a", float(k)), ("b", float(k % 2 == 0)))}
    stored = [int(e.split(" rows stored")[0].split()[-1].replace(",", "")) for e in errs]
    assert all(stored), errs  # both took a part of the stream


def test_bad_input_is_said_once_a_minute_per_topic_and_counted_every_time(
        fleet: Fleet, collectors: Collectors) -> None:
    broker = fleet.broker()
    out = fleet.tmp / "fleet.sqlite"
    col = collectors.start(broker.url, str(out), "--client-id", "bad-rate")
    wait_subscribed(col)
    publish(broker.port, [
        *[("pymb/gw/a", b"{not json")] * 5,
        ("pymb/gw/b", json.dumps({"time_utc": "yesterday", "values": {"v": 1}}).encode()),
        ("pymb/gw/c", json.dumps({"time_utc": T, "values": {"v": [[1]]}}).encode()),
        ("pymb/gw/dev", _sample(T, 1, v=1.0)),
    ])
    wait_rows(lambda: sqlite_count(out), 1, "the good sample behind the bad ones")
    err = stop(col)
    assert err.count("bad input on pymb/gw/a: not JSON") == 1, err
    assert err.count("bad input on pymb/gw/b: no time_utc") == 1, err
    assert err.count("bad input on pymb/gw/c: the value of v_1 is not a number") == 1, err
    assert ", 7 bad," in err, err
