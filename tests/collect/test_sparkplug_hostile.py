"""``pymb collect --profile sparkplug`` against edge nodes that follow Sparkplug B
3.0 to the letter or break it: messages made with pysparkplug's ``Payload``
(independent of pymb's encoder), published to a real mosquitto, the stored
rows and the rebirth requests read back as a user sees them."""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path
from typing import Any

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
from conftest import wait_until  # noqa: E402
from mqtt_broker import Fleet, Subscriber, db_count, db_ids, stop_log  # noqa: E402

from pymb.fleet.broker import Mosquitto  # noqa: E402
from pymb.fleet.health import DOWN_AFTER  # noqa: E402

pytest_plugins = ["mqtt_broker", "collectkit"]

GROUP = "plant"
T = 1800000000000  #: ms
DOUBLE, INT16, INT64, BOOLEAN = 10, 2, 4, 11


def _pb(pb: Any, seq: int | None, *metrics: dict[str, Any], ts: int = T) -> bytes:
    p = pb()
    p.timestamp = ts
    if seq is not None:
        p.seq = seq
    for d in metrics:
        m = p.metrics.add()
        for k, v in d.items():
            setattr(m, k, v)
    return bytes(p.SerializeToString())


def _births(pb: Any, node: str = "n1", device: str = "d1") -> list[tuple[str, bytes]]:
    """An NBIRTH (seq 0) with bdSeq, the rebirth metric and ``uptime``, and a DBIRTH
    (seq 1) of ``level`` (Int16, alias 7) and ``temp`` (Double, alias 8)."""
    return [
        (f"spBv1.0/{GROUP}/NBIRTH/{node}", _pb(
            pb, 0, {"name": "bdSeq", "datatype": INT64, "long_value": 1},
            {"name": "Node Control/Rebirth", "alias": 1, "datatype": BOOLEAN,
             "boolean_value": False, "timestamp": T},
            {"name": "uptime", "alias": 2, "datatype": INT64, "long_value": 10,
             "timestamp": T})),
        (f"spBv1.0/{GROUP}/DBIRTH/{node}/{device}", _pb(
            pb, 1, {"name": "level", "alias": 7, "datatype": INT16, "int_value": 5,
                    "timestamp": T},
            {"name": "temp", "alias": 8, "datatype": DOUBLE, "double_value": 20.0,
             "timestamp": T})),
    ]


def _collector(fleet: Fleet, collectors: Collectors, client_id: str
               ) -> tuple[Mosquitto, Subscriber, Path, Any]:
    broker = fleet.broker()
    ncmd = fleet.subscribe(broker, f"spBv1.0/{GROUP}/NCMD/#", client_id=f"{client_id}-ncmd")
    out = fleet.tmp / "fleet.sqlite"
    col = collectors.start(broker.url, str(out), "--profile", "sparkplug", "--group", GROUP,
                           "--host-id", "scada", "--client-id", client_id)
    wait_subscribed(col)
    return broker, ncmd, out, col


def test_data_by_name_without_a_datatype_take_the_births(
        fleet: Fleet, collectors: Collectors, sparkplug_pb: Any) -> None:
    """Sparkplug 3.0: data name a metric (by name, when a node uses no aliases)
    and should not repeat its datatype; the host reads the value as the birth
    declared it (an Int16's two's complement). Data naming a metric no birth
    declared, without a datatype, cannot be read: a rebirth request, nothing
    stored of that message."""
    pb = sparkplug_pb
    broker, ncmd, out, col = _collector(fleet, collectors, "hostile-names")
    publish(broker.port, [
        *_births(pb),
        (f"spBv1.0/{GROUP}/NDATA/n1", _pb(pb, 2, {"name": "uptime", "long_value": 11,
                                                  "timestamp": T + 1000})),
        (f"spBv1.0/{GROUP}/DDATA/n1/d1", _pb(pb, 3, {"name": "level", "int_value": 0xFFFE,
                                                     "timestamp": T + 1000},
                                             {"name": "temp", "double_value": 21.5,
                                              "timestamp": T + 1000})),
        # a name no birth declared, no datatype: the message is not stored
        (f"spBv1.0/{GROUP}/DDATA/n1/d1", _pb(pb, 4, {"name": "temp", "double_value": 22.5,
                                                     "timestamp": T + 2000},
                                             {"name": "pressure", "double_value": 1.0,
                                              "timestamp": T + 2000})),
        (f"spBv1.0/{GROUP}/DDATA/n1/d1", _pb(pb, 5, {"alias": 8, "double_value": 23.5,
                                                     "timestamp": T + 3000})),
    ])
    wait_rows(lambda: sqlite_count(out), 7, "the births' rows, the data's and the last")
    ncmd.wait_until(lambda m: m, 15, "the rebirth request of an undeclared metric")
    err = stop(col)
    assert "asked plant/n1 for a rebirth: DDATA with a metric 'pressure' no birth declared" \
        in err, err
    assert "0 bad" in err, err
    assert sorted(sqlite_facts(out)) == [
        ("n1", "", "uptime", 1800000000.0, 10.0, None, None, None),
        ("n1", "", "uptime", 1800000001.0, 11.0, None, None, None),
        ("n1", "d1", "level", 1800000000.0, 5.0, None, None, None),
        ("n1", "d1", "level", 1800000001.0, -2.0, None, None, None),
        ("n1", "d1", "temp", 1800000000.0, 20.0, None, None, None),
        ("n1", "d1", "temp", 1800000001.0, 21.5, None, None, None),
        ("n1", "d1", "temp", 1800000003.0, 23.5, None, None, None),
    ]


def test_a_devices_data_after_its_ddeath_are_read_with_its_dbirth(
        fleet: Fleet, collectors: Collectors, sparkplug_pb: Any) -> None:
    """A DDEATH leaves the device's DBIRTH in force: a board publishes the backlog
    of a device that is down (``is_historical``) after its DDEATH, by the aliases
    of that DBIRTH (docs/fleet.md). They are stored, and no rebirth is asked."""
    pb = sparkplug_pb
    broker, ncmd, out, col = _collector(fleet, collectors, "hostile-ddeath")
    publish(broker.port, [
        *_births(pb),
        (f"spBv1.0/{GROUP}/DDEATH/n1/d1", _pb(pb, 2)),
        (f"spBv1.0/{GROUP}/DDATA/n1/d1", _pb(pb, 3, {"alias": 8, "double_value": 19.0,
                                                     "timestamp": T - 1000,
                                                     "is_historical": True})),
        (f"spBv1.0/{GROUP}/DBIRTH/n1/d1", _pb(
            pb, 4, {"name": "temp", "alias": 8, "datatype": DOUBLE, "double_value": 21.0,
                    "timestamp": T + 2000})),
        (f"spBv1.0/{GROUP}/DDATA/n1/d1", _pb(pb, 5, {"alias": 8, "double_value": 22.0,
                                                     "timestamp": T + 3000})),
    ])
    wait_rows(lambda: sqlite_count(out), 6, "the rows of the births and the data")
    err = stop(col)
    assert "rebirth" not in err, err
    assert not ncmd.snapshot()
    assert sorted(f[1:5] for f in sqlite_facts(out)) == [
        ("", "uptime", 1800000000.0, 10.0),
        ("d1", "level", 1800000000.0, 5.0),
        ("d1", "temp", 1799999999.0, 19.0),
        ("d1", "temp", 1800000000.0, 20.0),
        ("d1", "temp", 1800000002.0, 21.0),
        ("d1", "temp", 1800000003.0, 22.0),
    ]


def test_its_own_state_said_offline_by_another_is_made_online_again(
        fleet: Fleet, collectors: Collectors) -> None:
    """Sparkplug 3.0: a host application subscribes to its own STATE and, told
    offline there (the late will of an earlier collector with this host id, on
    another machine), publishes it online again at once, with its will's
    timestamp, so that edge nodes that start later find it online. Its own
    offline (a clean stop, the STATE its start finds retained) is no such case."""
    broker = fleet.broker()
    out = str(fleet.tmp / "fleet.sqlite")
    args = ("--profile", "sparkplug", "--group", GROUP, "--host-id", "scada")
    col = collectors.start(broker.url, out, *args, "--client-id", "state-a")
    wait_subscribed(col)
    first = stop(col)  # retained now: offline, its own
    state = fleet.subscribe(broker, "spBv1.0/STATE/scada", client_id="state-watch")
    state.wait_until(lambda m: m, 15, "the retained STATE offline")
    col = collectors.start(broker.url, out, *args, "--client-id", "state-a")
    wait_subscribed(col)
    state.wait_until(lambda m: len(m) >= 2, 15, "the STATE online")
    online = json.loads(state.snapshot()[1][1])
    assert online["online"] is True
    stale = {"online": False, "timestamp": online["timestamp"] - 60000}
    publish(broker.port, [("spBv1.0/STATE/scada", json.dumps(stale).encode())], retain=True)
    state.wait_until(lambda m: len(m) >= 4, 15, "the STATE online again")
    assert [json.loads(p) for _, p in state.snapshot()[2:]] == [stale, online]
    late = fleet.subscribe(broker, "spBv1.0/STATE/scada", client_id="late-watch")
    late.wait_until(lambda m: m, 15, "the retained STATE")
    assert json.loads(late.snapshot()[0][1]) == online
    err = stop(col)
    state.wait_until(lambda m: len(m) >= 5, 15, "the STATE offline of the clean stop")
    assert json.loads(state.snapshot()[-1][1]) == {"online": False,
                                                   "timestamp": online["timestamp"]}
    assert "spBv1.0/STATE/scada said offline: published online again" in err, err
    assert "said offline" not in first, first
    assert err.count("said offline") == 1, err


def test_an_alias_a_birth_gives_two_metrics_stores_nothing_under_either(
        fleet: Fleet, collectors: Collectors, sparkplug_pb: Any) -> None:
    """Sparkplug: an alias of a birth names one metric. A DBIRTH that gives alias 7
    to two metrics is said; its named values are stored, data naming alias 7 are
    bad input (not stored under a name they may not have), the others are read."""
    pb = sparkplug_pb
    broker, ncmd, out, col = _collector(fleet, collectors, "hostile-alias")
    nbirth = _births(pb)[0]
    publish(broker.port, [
        nbirth,
        (f"spBv1.0/{GROUP}/DBIRTH/n1/d1", _pb(
            pb, 1, {"name": "level", "alias": 7, "datatype": INT16, "int_value": 5,
                    "timestamp": T},
            {"name": "temp", "alias": 7, "datatype": DOUBLE, "double_value": 20.0,
             "timestamp": T},
            {"name": "flow", "alias": 9, "datatype": DOUBLE, "double_value": 1.0,
             "timestamp": T})),
        (f"spBv1.0/{GROUP}/DDATA/n1/d1", _pb(pb, 2, {"alias": 7, "double_value": 21.0,
                                                     "timestamp": T + 1000})),
        (f"spBv1.0/{GROUP}/DDATA/n1/d1", _pb(pb, 3, {"alias": 9, "double_value": 2.0,
                                                     "timestamp": T + 1000})),
    ])
    wait_rows(lambda: sqlite_count(out), 5, "the births' rows and flow's data")
    err = stop(col)
    assert ("the DBIRTH of plant/n1/d1 gives alias 7 to 'level' and 'temp': data naming "
            "that alias are not stored") in err, err
    assert ("bad input on spBv1.0/plant/DDATA/n1/d1: alias 7 names two metrics of the "
            "birth ('level', 'temp')") in err, err
    assert "1 bad" in err, err
    assert not ncmd.snapshot()  # a rebirth would bring the same birth
    assert sorted(f[1:5] for f in sqlite_facts(out)) == [
        ("", "uptime", 1800000000.0, 10.0),
        ("d1", "flow", 1800000000.0, 1.0),
        ("d1", "flow", 1800000001.0, 2.0),
        ("d1", "level", 1800000000.0, 5.0),
        ("d1", "temp", 1800000000.0, 20.0),
    ]


def test_a_boards_backlog_of_a_device_that_is_down_is_stored_once(
        fleet: Fleet, collectors: Collectors) -> None:
    """pymb's own board, end to end: samples logged while the broker is away,
    then the device stops answering. When the broker is back the board sends
    NBIRTH, the device's DBIRTH and DDEATH, then the backlog as historical DDATA:
    every sample id the board logged is stored once by the collector."""
    broker = fleet.broker()
    out = fleet.tmp / "fleet.sqlite"
    col = collectors.start(broker.url, str(out), "--profile", "sparkplug", "--group", GROUP,
                           "--host-id", "scada", "--client-id", "backlog")
    wait_subscribed(col)
    sim = fleet.simulator("coolpro")
    log_db = fleet.tmp / "board.sqlite"
    log = fleet.log(sim.endpoint, log_db, "--mqtt", broker.url, "--mqtt-profile", "sparkplug",
                    "--mqtt-group", GROUP, "--mqtt-node", "gw1")
    wait_rows(lambda: sqlite_count(out), 200, "live rows")
    broker.stop()
    before = db_count(log_db)
    wait_until(lambda: db_count(log_db) >= before + 50, "samples while the broker is away", 30)
    sim.stop()

    def faults() -> int:
        con = sqlite3.connect(f"file:{log_db}?mode=ro", uri=True)
        try:
            return int(con.execute("SELECT COUNT(*) FROM events WHERE kind IN "
                                   "('timeout', 'connection', 'protocol', 'error')"
                                   ).fetchone()[0])
        finally:
            con.close()
    wait_until(lambda: faults() >= DOWN_AFTER, "the device down", 60)
    broker.start()
    ids = db_ids(log_db)

    def stored() -> set[int]:
        return {int(f[4]) for f in sqlite_facts(out) if f[2] == "sample" and f[4] is not None}
    wait_until(lambda: ids <= stored(), lambda: f"{len(ids - stored())} of the board's "
               "samples not stored", 90)
    stop_log(log)
    err = stop(col)
    samples = [int(f[4]) for f in sqlite_facts(out) if f[2] == "sample" and f[4] is not None]
    assert len(samples) == len(set(samples)), "a sample stored twice"
    assert "0 bad" in err, err


def test_a_broker_that_refuses_its_state_is_said(
        fleet: Fleet, collectors: Collectors, sparkplug_pb: Any, tmp_path: Path) -> None:
    """An ACL that lets the collector read its STATE topic and not write it: the
    broker's PUBACK refuses the STATE online (MQTT 5, Not authorized), so boards
    that wait for this primary host publish nothing; the collector says so, with
    the host id, and still stores what the boards it can read send."""
    acl = tmp_path / "acl"
    acl.write_text(f"topic read spBv1.0/STATE/#\ntopic readwrite spBv1.0/{GROUP}/#\n")
    # (mosquitto 2.0.11 drops a client after refusing its message when
    # max_queued_messages is 0, as the fleet tests' brokers have it; its default is 1000)
    broker = fleet.broker(extra=("max_queued_messages 1000", f"acl_file {acl}"))
    out = fleet.tmp / "fleet.sqlite"
    col = collectors.start(broker.url, str(out), "--profile", "sparkplug", "--group", GROUP,
                           "--host-id", "scada", "--client-id", "state-refused")
    nbirth = [(f"spBv1.0/{GROUP}/NBIRTH/n1", _pb(
        sparkplug_pb, 0, {"name": "bdSeq", "datatype": INT64, "long_value": 0},
        {"name": "t", "alias": 2, "datatype": DOUBLE, "double_value": 1.5, "timestamp": T}))]
    # published until stored (once: the row's key), its stderr read only at the end
    # (the refusal comes with the line that says it subscribed)
    def stored() -> bool:
        publish(broker.port, nbirth)
        return sqlite_count(out) >= 1

    wait_until(stored, "the NBIRTH's row", 30, every=0.5)
    err = stop(col)
    said = [line for line in err.splitlines() if "spBv1.0/STATE/scada" in line]
    assert len(said) == 1, err
    assert "refused" in said[0]
    assert "Not authorized" in said[0]
    assert "--mqtt-primary-host scada" in said[0]
