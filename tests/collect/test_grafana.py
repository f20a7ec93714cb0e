"""contrib/grafana: the data source provisioning file and the dashboard fit
together (Grafana 10+, the PostgreSQL data source by its uid, node/device/point
variables, a time series and a table of the latest values), and every panel's
and variable's SQL, with Grafana's macros replaced as Grafana's PostgreSQL data
source replaces them, runs against a real PostgreSQL after a collection and
returns what was collected."""

from __future__ import annotations

import json
import re
from datetime import UTC, datetime
from typing import Any

import pytest

pytest.register_assert_rewrite("mqtt_broker", "collectkit")
from collectkit import Collectors, pg_count, psycopg, publish, stop, wait_rows, wait_subscribed  # noqa: E402
from conftest import ROOT  # noqa: E402
from mqtt_broker import Fleet  # noqa: E402

from pymb.collect.postgres import Postgres  # noqa: E402

pytest_plugins = ["mqtt_broker", "collectkit"]

GRAFANA = ROOT / "contrib" / "grafana"
DASHBOARD = json.loads((GRAFANA / "pymb-fleet.json").read_text())
PROVISIONING = (GRAFANA / "datasource.yaml").read_text()


def _setting(text: str, key: str) -> str:
    m = re.search(rf"^\s*-?\s*{key}: (\S+)$", text, re.M)
    assert m, key
    return m.group(1)


def _queries() -> list[tuple[str, str]]:
    """(where, SQL) of every variable and panel target."""
    out = [(f"variable {v['name']}", v["query"]) for v in DASHBOARD["templating"]["list"]]
    for p in DASHBOARD["panels"]:
        out += [(f"panel {p['title']!r} {t['refId']}", t["rawSql"]) for t in p["targets"]]
    return out


def test_the_dashboard_fits_the_provisioned_data_source() -> None:
    uid = _setting(PROVISIONING, "uid")
    assert _setting(PROVISIONING, "type") == "postgres"
    assert _setting(PROVISIONING, "apiVersion") == "1"
    assert DASHBOARD["schemaVersion"] >= 36  # Grafana 10's dashboards are 37+
    assert DASHBOARD["uid"] == "pymb-fleet"
    assert DASHBOARD["title"]
    names = [v["name"] for v in DASHBOARD["templating"]["list"]]
    assert names == ["node", "device", "point"]
    kinds = [p["type"] for p in DASHBOARD["panels"]]
    assert "timeseries" in kinds
    assert "table" in kinds
    assert len({p["id"] for p in DASHBOARD["panels"]}) == len(kinds)
    for thing in [*DASHBOARD["templating"]["list"], *DASHBOARD["panels"],
                  *(t for p in DASHBOARD["panels"] for t in p["targets"])]:
        assert thing["datasource"] == {"type": "postgres", "uid": uid}
    for p in DASHBOARD["panels"]:
        assert set(p["gridPos"]) == {"h", "w", "x", "y"}
        for t in p["targets"]:
            assert t["rawQuery"] is True
            assert t["editorMode"] == "code"
            assert t["format"] == ("time_series" if p["type"] == "timeseries" else "table")


def _expand(sql: str, start: datetime, end: datetime, values: dict[str, list[str]],
            interval_s: int) -> str:
    """SQL with Grafana's macros and variables replaced as Grafana does."""
    frm, to = f"'{start.isoformat()}'", f"'{end.isoformat()}'"
    sql = re.sub(r"\$__timeFilter\((\w+)\)", rf"\1 BETWEEN {frm} AND {to}", sql)
    sql = re.sub(r"\$__timeGroupAlias\((\w+), \$__interval\)",
                 rf'floor(extract(epoch from \1)/{interval_s})*{interval_s} AS "time"', sql)
    sql = sql.replace("$__timeFrom()", frm).replace("$__timeTo()", to)
    for name, vals in values.items():
        sql = sql.replace(f"${name}", ",".join("'" + v.replace("'", "''") + "'"
                                               for v in vals))
    assert "$" not in sql, sql
    return sql


def _run(url: str, sql: str) -> list[tuple[Any, ...]]:
    with psycopg.connect(url) as con:
        return list(con.execute(sql.encode()).fetchall())


def test_every_query_runs_on_collected_data(fleet: Fleet, collectors: Collectors,
                                            postgres: Postgres) -> None:
    broker = fleet.broker()
    col = collectors.start(broker.url, postgres.url, "--client-id", "graf")
    wait_subscribed(col)
    now = datetime.now(UTC).timestamp()
    msgs = []
    for node in ("gw1", "gw2"):
        for k in range(5):
            doc = {"time_utc": now - 60 + k * 10, "sample": k + 1,
                   "values": {"voltage_v": 230.0 + k, "label": "tank",
                              "temperature_c": [20.5, None]},
                   "states": {"temperature_c": [None, "offline"]}}
            msgs.append((f"pymb/{node}/meter-1", json.dumps(doc).encode()))
    publish(broker.port, msgs)
    wait_rows(lambda: pg_count(postgres.url), 2 * 5 * 4, "the collection")
    stop(col)
    start = datetime.fromtimestamp(now - 3600, UTC)
    end = datetime.fromtimestamp(now + 60, UTC)
    values: dict[str, list[str]] = {}
    for where, sql in _queries()[:3]:  # the variables, each with those before it
        rows = _run(postgres.url, _expand(sql, start, end, values, 60))
        values[where.split()[-1]] = [r[0] for r in rows]
    assert values == {"node": ["gw1", "gw2"], "device": ["meter-1"],
                      "point": ["label", "temperature_c_1", "temperature_c_2", "voltage_v"]}
    results = {where: _run(postgres.url, _expand(sql, start, end, values, 10))
               for where, sql in _queries()[3:]}
    series = results["panel 'Values' A"]
    assert {r[1] for r in series} == {"gw1/meter-1/voltage_v", "gw2/meter-1/voltage_v",
                                      "gw1/meter-1/temperature_c_1",
                                      "gw2/meter-1/temperature_c_1"}
    assert sum(1 for r in series if r[1] == "gw1/meter-1/voltage_v") == 5  # 10 s apart
    latest = results["panel 'Latest values' A"]
    assert len(latest) == 8
    assert latest[-1][:3] == ("gw2", "meter-1", "voltage_v")
    assert latest[-1][4] == 234.0  # the newest sample's value
    assert sorted(r[:4] for r in results["panel 'No value: why' A"]) == [
        ("gw1", "meter-1", "offline", 5), ("gw2", "meter-1", "offline", 5)]
    lag = results["panel 'Collector lag (s)' A"]
    assert {r[1] for r in lag} == {"gw1", "gw2"}
    assert all(r[2] > 0 for r in lag)
