"""``pymb collect --profile sparkplug``: a host application, end to end with
``pymb log --mqtt-profile sparkplug`` boards (rows compared with what an
independent subscriber decoded with pysparkplug's ``Payload``), its STATE
(retained, will), and rebirth requests on a seq gap and on data with no
birth, at most once per node per 5 s, against messages made by pysparkplug."""

from __future__ import annotations

import json
import signal
import sqlite3
import threading
import time
from pathlib import Path
from typing import Any

import pytest

pytest.register_assert_rewrite("mqtt_broker", "collectkit")
from collectkit import (  # noqa: E402
    Collectors,
    Fact,
    pg_count,
    publish,
    same_facts,
    sqlite_count,
    sqlite_facts,
    stop,
    wait_rows,
    wait_subscribed,
)
from conftest import wait_until  # noqa: E402
from mqtt_broker import Fleet, db_count, db_ids, stop_log  # noqa: E402

from pymb.collect import collector as collector_module  # noqa: E402
from pymb.collect.postgres import Postgres  # noqa: E402
from pymb.collect.sqlstore import open_stores  # noqa: E402
from pymb.fleet.config import MqttConfig  # noqa: E402

pytest_plugins = ["mqtt_broker", "collectkit"]

GROUP = "plant"


def _value(m: Any) -> tuple[float | None, str | None]:
    kind = m.WhichOneof("value")
    v = getattr(m, kind) if kind else None
    if isinstance(v, str):
        return None, v
    if v is None:
        return None, None
    if m.datatype in (1, 2, 3) and kind == "int_value":  # Int8/16/32 on a uint32
        bits = {1: 8, 2: 16, 3: 32}[m.datatype]
        v = v - (1 << bits) if v >= 1 << (bits - 1) else v
    return float(v), None


def expected_sparkplug(pb: Any, messages: list[tuple[str, bytes]]) -> set[Fact]:
    """The facts of births and data as an independent decoder reads them: aliases
    from the births, a metric's own timestamp, node metrics with device ""."""
    aliases: dict[tuple[str, str], dict[int, str]] = {}
    out: set[Fact] = set()
    for topic, payload in messages:
        parts = topic.split("/")
        kind, node = parts[2], parts[3]
        device = parts[4] if len(parts) > 4 else ""
        if kind not in ("NBIRTH", "DBIRTH", "NDATA", "DDATA"):
            continue
        p = pb.FromString(payload)
        names = aliases.setdefault((node, device), {})
        for m in p.metrics:
            if kind.endswith("BIRTH") and m.HasField("alias"):
                names[m.alias] = m.name
            name = m.name or names[m.alias]
            if name == "bdSeq" or name.startswith("Node Control/"):
                continue
            if name.startswith("channel "):
                ch, q = name[len("channel "):].split("/", 1)
                name = f"{q}_{int(ch)}"
            t = m.timestamp / 1000
            if m.is_null:
                keys = list(m.properties.keys)
                st = (m.properties.values[keys.index("state")].string_value
                      if "state" in keys else "no_value")
                out.add((node, device, name, t, None, None, st, None))
            else:
                v, text = _value(m)
                out.add((node, device, name, t, v, text, None, None))
    return out


def test_sparkplug_board_to_sqlite_value_by_value(
        fleet: Fleet, collectors: Collectors, sparkplug_pb: Any) -> None:
    broker = fleet.broker()
    sim = fleet.simulator("coolpro")
    sub = fleet.subscribe(broker, f"spBv1.0/{GROUP}/#")
    out = fleet.tmp / "fleet.sqlite"
    col = collectors.start(broker.url, str(out), "--profile", "sparkplug", "--group", GROUP,
                           "--host-id", "scada", "--client-id", "sp1")
    wait_subscribed(col)
    log_db = fleet.tmp / "board.sqlite"
    log = fleet.log(sim.endpoint, log_db, "--mqtt", broker.url, "--mqtt-profile", "sparkplug",
                    "--mqtt-group", GROUP, "--mqtt-node", "gw1", "--mqtt-primary-host", "scada",
                    seconds=3)
    _, log_err = log.communicate(timeout=60)
    assert log.returncode == 0, log_err  # it published: the collector's STATE said online
    wait_until(lambda: sub.snapshot() and sub.snapshot()[-1][0].endswith("/NDEATH/gw1"),
               "the board's NDEATH", 30)
    expected = expected_sparkplug(sparkplug_pb, sub.snapshot())
    assert len({f[1] for f in expected}) == 2  # the node's own metrics and the CoolPro's
    wait_rows(lambda: sqlite_count(out), len(expected), "every value stored")
    err = stop(col)
    same_facts(sqlite_facts(out), expected)
    assert "0 bad" in err
    assert "rebirth" not in err, err


def _pb(pb: Any, seq: int | None, *metrics: dict[str, Any], ts: int = 1800000000000) -> bytes:
    p = pb()
    p.timestamp = ts
    if seq is not None:
        p.seq = seq
    for d in metrics:
        m = p.metrics.add()
        for k, v in d.items():
            setattr(m, k, v)
    return bytes(p.SerializeToString())


def test_state_rebirth_on_a_seq_gap_and_on_data_without_birth(
        fleet: Fleet, collectors: Collectors, sparkplug_pb: Any) -> None:
    pb = sparkplug_pb
    broker = fleet.broker()
    state = fleet.subscribe(broker, "spBv1.0/STATE/scada", client_id="state-watch")
    ncmd = fleet.subscribe(broker, f"spBv1.0/{GROUP}/NCMD/#", client_id="ncmd-watch")
    out = fleet.tmp / "fleet.sqlite"
    args = ("--profile", "sparkplug", "--group", GROUP, "--host-id", "scada",
            "--client-id", "sp2")
    col = collectors.start(broker.url, str(out), *args)
    wait_subscribed(col)
    state.wait_until(lambda m: m, 15, "the host's STATE")
    online = json.loads(state.snapshot()[0][1])
    assert online["online"] is True
    assert isinstance(online["timestamp"], int)
    late = fleet.subscribe(broker, "spBv1.0/STATE/scada", client_id="late-watch")
    late.wait_until(lambda m: m, 15, "the retained STATE")
    assert late.flags[0] == (1, True)  # retained, QoS 1
    assert json.loads(late.snapshot()[0][1]) == online
    t = 1800000000000
    publish(broker.port, [
        # data before any birth: a rebirth request, nothing stored
        (f"spBv1.0/{GROUP}/DDATA/n1/d1", _pb(pb, 5, {"alias": 7, "datatype": 10,
                                                     "double_value": 1.0, "timestamp": t})),
    ])
    ncmd.wait_until(lambda m: m, 15, "the NCMD of data with no birth")
    topic, payload = ncmd.snapshot()[0]
    assert topic == f"spBv1.0/{GROUP}/NCMD/n1"
    cmd = pb.FromString(payload).metrics[0]
    assert (cmd.name, cmd.datatype, cmd.boolean_value) == ("Node Control/Rebirth", 11, True)
    time.sleep(5.2)  # the next request of n1 may come 5 s after the first
    publish(broker.port, [
        (f"spBv1.0/{GROUP}/NBIRTH/n1", _pb(pb, 0, {"name": "bdSeq", "datatype": 4,
                                                   "long_value": 3},
                                           {"name": "Node Control/Rebirth", "alias": 1,
                                            "datatype": 11, "boolean_value": False},
                                           {"name": "uptime", "alias": 2, "datatype": 8,
                                            "long_value": 99, "timestamp": t})),
        (f"spBv1.0/{GROUP}/DBIRTH/n1/d1", _pb(
            pb, 1, {"name": "channel 002/temperature_c", "alias": 7, "datatype": 10,
                    "double_value": 20.5, "timestamp": t},
            {"name": "label", "alias": 8, "datatype": 12, "string_value": "tank",
             "timestamp": t},
            {"name": "level", "alias": 9, "datatype": 2, "int_value": 0xFFFE,
             "timestamp": t})),
        (f"spBv1.0/{GROUP}/DDATA/n1/d1", _pb(pb, 2, {"alias": 7, "datatype": 10,
                                                     "double_value": 21.0,
                                                     "timestamp": t + 1000},
                                             {"alias": 9, "datatype": 2, "is_null": True,
                                              "timestamp": t + 1000})),
        # seq 3 lost: a gap, and one request only for the two gaps within 5 s
        (f"spBv1.0/{GROUP}/DDATA/n1/d1", _pb(pb, 4, {"alias": 7, "datatype": 10,
                                                     "double_value": 22.0,
                                                     "timestamp": t + 2000})),
        (f"spBv1.0/{GROUP}/DDATA/n1/d1", _pb(pb, 7, {"alias": 7, "datatype": 10,
                                                     "double_value": 23.0,
                                                     "timestamp": t + 3000})),
        (f"spBv1.0/{GROUP}/BOGUS/n1", b"x"),
        (f"spBv1.0/{GROUP}/DDATA/n1/d1", b"\xff\xff\xff"),
    ])
    wait_rows(lambda: sqlite_count(out), 7, "the rows of the births and data")
    ncmd.wait_until(lambda m: len(m) >= 2, 15, "the NCMD of the seq gap")
    time.sleep(1.0)
    assert len(ncmd.snapshot()) == 2, "at most one rebirth request per node per 5 s"
    col.send_signal(signal.SIGKILL)
    _, err = col.communicate(timeout=30)
    for what in (f"bad input on spBv1.0/{GROUP}/BOGUS/n1: not a Sparkplug B topic",
                 f"bad input on spBv1.0/{GROUP}/DDATA/n1/d1: not a Sparkplug B payload",
                 f"asked {GROUP}/n1 for a rebirth: DDATA before its NBIRTH",
                 f"asked {GROUP}/n1 for a rebirth: seq 4 after 2"):
        assert what in err, err
    state.wait_until(lambda m: len(m) >= 2, 15, "the will: STATE offline")
    will = json.loads(state.snapshot()[-1][1])
    assert will == {"online": False, "timestamp": online["timestamp"]}
    col = collectors.start(broker.url, str(out), *args)
    wait_subscribed(col)
    state.wait_until(lambda m: len(m) >= 3 and json.loads(m[-1][1])["online"], 15,
                     "STATE online again")
    stop(col)
    state.wait_until(lambda m: not json.loads(m[-1][1])["online"], 15,
                     "STATE offline on a clean stop")
    assert sorted(sqlite_facts(out)) == [
        ("n1", "", "uptime", 1800000000.0, 99.0, None, None, None),
        ("n1", "d1", "label", 1800000000.0, None, "tank", None, None),
        ("n1", "d1", "level", 1800000000.0, -2.0, None, None, None),
        ("n1", "d1", "level", 1800000001.0, None, None, "no_value", None),
        ("n1", "d1", "temperature_c_2", 1800000000.0, 20.5, None, None, None),
        ("n1", "d1", "temperature_c_2", 1800000001.0, 21.0, None, None, None),
        ("n1", "d1", "temperature_c_2", 1800000002.0, 22.0, None, None, None),
        ("n1", "d1", "temperature_c_2", 1800000003.0, 23.0, None, None, None),
    ]


def _stored_samples(path: Path) -> set[int]:
    """The ``sample`` metric's values a collector stored (a pymb board's sample ids)."""
    if not path.exists():
        return set()
    try:
        con = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
        try:
            return {int(v) for (v,) in con.execute(
                "SELECT value FROM pymb_values WHERE point = 'sample'")}
        finally:
            con.close()
    except sqlite3.Error:
        return set()


def test_a_broker_restart_loses_nothing_with_the_collector_as_primary_host(
        fleet: Fleet, collectors: Collectors) -> None:
    """A board whose --mqtt-primary-host is the collector: the broker restarted
    (Debian's default, QoS 0 not queued for a client that is away), the board
    back before the collector, and every sample of the board is stored. The
    broker's shutdown publishes the collector's will (STATE offline, retained):
    the board waits for its STATE online, then sends the outage as history.
    (Without --mqtt-primary-host, what the board sends before the collector is
    back is lost: QoS 0.)"""
    broker = fleet.broker(extra=("queue_qos0_messages false",))
    sim = fleet.simulator("coolpro")
    out = fleet.tmp / "fleet.sqlite"
    col = collectors.start(broker.url, str(out), "--profile", "sparkplug", "--group", GROUP,
                           "--host-id", "scada", "--client-id", "sp-restart")
    wait_subscribed(col)
    log_db = fleet.tmp / "board.sqlite"
    log = fleet.log(sim.endpoint, log_db, "--mqtt", broker.url, "--mqtt-profile", "sparkplug",
                    "--mqtt-group", GROUP, "--mqtt-node", "gw1", "--mqtt-primary-host", "scada")
    wait_until(lambda: len(_stored_samples(out)) >= 50, "50 samples stored", 30)
    broker.stop()
    before = db_count(log_db)
    wait_until(lambda: db_count(log_db) >= before + 100, "100 samples logged while down", 30)
    broker.start()
    wait_until(lambda: db_ids(log_db) - _stored_samples(out) == set(), lambda:
               f"the outage's samples stored; {len(db_ids(log_db) - _stored_samples(out))} "
               "not yet", 60)
    stop_log(log)
    wait_until(lambda: db_ids(log_db) <= _stored_samples(out), "every sample stored", 30)
    err = stop(col)
    assert "0 bad" in err


def test_a_clean_stop_of_the_collector_loses_nothing_of_a_board_that_waits_for_it(
        fleet: Fleet, collectors: Collectors) -> None:
    """The collector stopped (SIGTERM) while a board that has it as primary host
    publishes, then started again: every sample of the board is stored. The
    collector says offline first, so that the board stops (NDEATH) and keeps what
    it logs, and stores what the board sent before that (QoS 0: nothing the broker
    handed it comes again), then ends; the board sends the rest as history once
    the collector is back."""
    broker = fleet.broker(extra=("queue_qos0_messages false",))
    sim = fleet.simulator("coolpro")
    out = fleet.tmp / "fleet.sqlite"
    args = ("--profile", "sparkplug", "--group", GROUP, "--host-id", "scada",
            "--client-id", "sp-stop")
    col = collectors.start(broker.url, str(out), *args)
    wait_subscribed(col)
    log_db = fleet.tmp / "board.sqlite"
    log = fleet.log(sim.endpoint, log_db, "--mqtt", broker.url, "--mqtt-profile", "sparkplug",
                    "--mqtt-group", GROUP, "--mqtt-node", "gw1", "--mqtt-primary-host", "scada")
    wait_until(lambda: len(_stored_samples(out)) >= 200, "200 samples stored", 30)
    stop(col)
    stopped = db_count(log_db)
    wait_until(lambda: db_count(log_db) >= stopped + 50, "50 samples logged meanwhile", 30)
    col = collectors.start(broker.url, str(out), *args)
    wait_subscribed(col)
    wait_until(lambda: len(_stored_samples(out)) >= stopped + 50, "the samples of the pause "
               "stored", 60)
    stop_log(log)
    wait_until(lambda: db_ids(log_db) <= _stored_samples(out), lambda:
               f"every sample stored; {sorted(db_ids(log_db) - _stored_samples(out))[:10]} "
               "are not", 30)
    stop(col)


def test_qos0_data_beyond_the_inbox_are_dropped_and_a_rebirth_asked(
        fleet: Fleet, postgres: Postgres, sparkplug_pb: Any,
        monkeypatch: pytest.MonkeyPatch) -> None:
    """While PostgreSQL is down, QoS 0 data pile up: beyond MAX_INBOX waiting
    messages they are dropped (counted, an event), the seq gap brings a
    rebirth request, and what was kept is stored when PostgreSQL is back."""
    pb = sparkplug_pb
    monkeypatch.setattr(collector_module, "MAX_INBOX", 20)
    monkeypatch.setattr(collector_module, "MAX_BATCH", 5)
    broker = fleet.broker()
    ncmd = fleet.subscribe(broker, f"spBv1.0/{GROUP}/NCMD/#", client_id="ncmd-watch")
    events: list[str] = []
    cfg = collector_module.CollectConfig(
        mqtt=MqttConfig(url=broker.url, node="collector", group=GROUP), out=postgres.url,
        profile="sparkplug", host_id="h", client_id="drop1")
    col = collector_module.Collector(cfg, open_stores(postgres.url), events.append)
    col.connect()
    runner = threading.Thread(target=col.run, daemon=True)
    runner.start()
    try:
        t = 1800000000000
        publish(broker.port, [
            (f"spBv1.0/{GROUP}/NBIRTH/n1", _pb(pb, 0, {"name": "bdSeq", "datatype": 4,
                                                       "long_value": 0})),
            (f"spBv1.0/{GROUP}/DBIRTH/n1/d1", _pb(pb, 1, {"name": "v", "alias": 7,
                                                          "datatype": 10, "double_value": 0.0,
                                                          "timestamp": t}))])
        wait_rows(lambda: pg_count(postgres.url), 1, "the birth's row")
        postgres.stop()
        publish(broker.port, [(f"spBv1.0/{GROUP}/DDATA/n1/d1",
                               _pb(pb, (2 + k) % 256, {"alias": 7, "datatype": 10,
                                                       "double_value": float(k),
                                                       "timestamp": t + 1000 * (k + 1)}))
                              for k in range(200)], qos=0)
        wait_until(lambda: col.stats.dropped > 0, "dropped QoS 0 messages", 30)
        time.sleep(1.0)  # the rest of the 200 arrive (and are dropped)
        postgres.start()
        kept = 200 - col.stats.dropped
        wait_rows(lambda: pg_count(postgres.url), 1 + kept, "what was kept")
        # the next message shows the gap the drops left
        publish(broker.port, [(f"spBv1.0/{GROUP}/DDATA/n1/d1",
                               _pb(pb, 202 % 256, {"alias": 7, "datatype": 10,
                                                   "double_value": 200.0,
                                                   "timestamp": t + 201000}))], qos=0)
        ncmd.wait_until(lambda m: m, 30, "the rebirth request of the seq gap")
        wait_rows(lambda: pg_count(postgres.url), 2 + kept, "the message after the gap")
    finally:
        col.stop.set()
        runner.join(60)
    assert pg_count(postgres.url) == 2 + kept
    assert any(e.startswith("dropped ") and "QoS 0 messages" in e for e in events), events
    assert any("rebirth" in e for e in events), events


def test_the_hosts_state_message_is_made_where_it_is_read() -> None:
    """``pymb.collect.sparkplug`` gives the STATE message a primary host
    publishes (Sparkplug 3.0: JSON, ``online`` and ``timestamp``)."""
    import json

    from pymb.collect import sparkplug

    assert "state_payload" in sparkplug.__all__
    state = json.loads(sparkplug.state_payload(True, 1700000000000))
    assert state == {"online": True, "timestamp": 1700000000000}
