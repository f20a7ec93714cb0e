"""``pymb collect`` into a real PostgreSQL (Debian's, started in a temporary
folder by the ``postgres`` fixture): rows compared value by value with an
independent subscriber while PostgreSQL is down for 10 s, and 2 or 3
collectors sharing the stream (``--share``), one of them killed and started
again."""

from __future__ import annotations

import signal
import time

import pytest

pytest.register_assert_rewrite("mqtt_broker", "collectkit")
from collectkit import (  # noqa: E402
    Collectors,
    all_received,
    expected_plain,
    pg_count,
    pg_facts,
    psycopg,
    same_facts,
    stop,
    wait_rows,
    wait_subscribed,
)
from conftest import wait_until  # noqa: E402
from mqtt_broker import Fleet, db_count, stop_log  # noqa: E402

from pymb.collect.postgres import Postgres  # noqa: E402

pytest_plugins = ["mqtt_broker", "collectkit"]


def test_postgresql_down_for_10_s_while_messages_flow(
        fleet: Fleet, collectors: Collectors, postgres: Postgres) -> None:
    broker = fleet.broker()
    sim = fleet.simulator("coolpro")
    sub = fleet.subscribe(broker, "pymb/+/+")
    col = collectors.start(broker.url, postgres.url, "--client-id", "pg1")
    wait_subscribed(col)
    log_db = fleet.tmp / "board.sqlite"
    log = fleet.log(sim.endpoint, log_db, "--mqtt", broker.url, "--mqtt-node", "gw1")
    wait_rows(lambda: pg_count(postgres.url), 500, "rows before PostgreSQL stops")
    postgres.stop()
    before = db_count(log_db)
    time.sleep(10)  # refusing connections for 10 s while the board publishes
    assert db_count(log_db) > before + 100
    assert col.poll() is None
    postgres.start()
    stop_log(log)
    expected = all_received(sub, log_db)
    facts = expected_plain(expected)
    wait_rows(lambda: pg_count(postgres.url), len(facts), "every value stored")
    err = stop(col)
    same_facts(pg_facts(postgres.url), facts, us=True)
    assert "holding its messages unacknowledged" in err, err
    assert "the database takes rows again" in err, err
    with psycopg.connect(postgres.url) as con:
        latest = con.execute("SELECT count(*), count(DISTINCT (node, device, point)) "
                             "FROM pymb_latest").fetchone()
        newest = con.execute("SELECT max(time) FROM pymb_values").fetchone()
        at_newest = con.execute("SELECT count(*) FROM pymb_latest WHERE time = %s",
                                newest).fetchone()
    assert latest[0] == latest[1] == len({f[:3] for f in facts})
    with psycopg.connect(postgres.url) as con:
        indexes = {r[0]: r[1] for r in con.execute(
            "SELECT indexname, indexdef FROM pg_indexes WHERE tablename = 'pymb_values'")}
        timescale = con.execute("SELECT count(*) FROM pg_extension "
                                "WHERE extname = 'timescaledb'").fetchone()
    assert timescale == (0,)  # not installed here: a plain table, with its two indexes
    assert indexes["pymb_values_key"].endswith("(node, device, point, \"time\")")
    assert indexes["pymb_values_device_point"].endswith("(device, point, \"time\")")
    assert at_newest[0] == latest[0]  # one CoolPro: every point's newest is the last sample


@pytest.mark.parametrize("n", [2, 3])
def test_collectors_share_the_stream_one_killed(
        fleet: Fleet, collectors: Collectors, postgres: Postgres, n: int) -> None:
    broker = fleet.broker()
    sim = fleet.simulator("coolpro")
    sub = fleet.subscribe(broker, "pymb/+/+")
    cols = []
    for i in range(n):
        cols.append(collectors.start(broker.url, postgres.url, "--share", "fleet",
                                     "--client-id", f"share{i}"))
    for c in cols:
        wait_subscribed(c)
    log_db = fleet.tmp / "board.sqlite"
    log = fleet.log(sim.endpoint, log_db, "--mqtt", broker.url, "--mqtt-node", "gw1")
    wait_rows(lambda: pg_count(postgres.url), 1000, "rows before the kill")
    cols[0].send_signal(signal.SIGKILL)
    cols[0].communicate(timeout=30)
    before = db_count(log_db)
    wait_until(lambda: db_count(log_db) >= before + 200, "200 samples after the kill", 30)
    cols[0] = collectors.start(broker.url, postgres.url, "--share", "fleet",
                               "--client-id", "share0")
    wait_subscribed(cols[0])
    stop_log(log)
    facts = expected_plain(all_received(sub, log_db))
    wait_rows(lambda: pg_count(postgres.url), len(facts), "every value stored")
    errs = [stop(c) for c in cols]
    same_facts(pg_facts(postgres.url), facts, us=True)
    stored = [int(e.split(" rows stored")[0].split()[-1].replace(",", "")) for e in errs]
    assert all(s > 0 for s in stored[1:]), errs  # every survivor took its share
