"""docs/collect.md's examples, run: the picture names the parts, the command
lines run (the broker and PostgreSQL of the examples are the tests' own), the
broker settings are those of the tests' broker, the SQL runs on collected data,
the status line is pymb's."""

from __future__ import annotations

import json
import shlex
import subprocess
import time
from pathlib import Path

import pytest

pytest.register_assert_rewrite("mqtt_broker", "collectkit")
from collectkit import (  # noqa: E402
    pg_count,
    psycopg,
    publish,
    sqlite_count,
    stop,
    wait_rows,
    wait_subscribed,
)
from conftest import PYMB, PYMB_ENV  # noqa: E402
from docblocks import assert_shaped, claim, claim_one  # noqa: E402
from mqtt_broker import Fleet  # noqa: E402

from pymb.collect.collector import CollectStats  # noqa: E402
from pymb.collect.postgres import Postgres  # noqa: E402
from pymb.commands.collect import status_text  # noqa: E402

pytest_plugins = ["mqtt_broker", "collectkit"]



def _start(line: str, broker_url: str, pg_url: str, cwd: Path) -> subprocess.Popen[str]:
    line = line.split("#")[0].strip().removesuffix("&").strip()
    argv = shlex.split(line.replace("mqtt://localhost", broker_url)
                       .replace("postgresql://pymb@localhost/pymb", pg_url))
    assert argv[0] == "pymb", line
    return subprocess.Popen([*PYMB, *argv[1:]], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=PYMB_ENV, cwd=cwd)


def _samples(n: int) -> list[tuple[str, bytes]]:
    now = time.time()
    return [(f"pymb/board-{b}/sdm630-1", json.dumps(
        {"time_utc": now - 10 + k, "sample": k + 1, "values": {"voltage_v": 230.0 + k,
                                                               "current_a": 1.5}}).encode())
            for b in range(n) for k in range(3)]


def test_the_picture_goes_from_board_to_dashboard() -> None:
    text = claim_one("docs/collect.md", "text", how="check", index=0).text
    for part in ("pymb log --mqtt", "mosquitto", "pymb collect", "--share", "PostgreSQL",
                 "SQLite", "Grafana", "pymb_values", "pymb_latest", "acknowledges"):
        assert part in text, part


def test_the_broker_settings_are_the_tests_brokers(fleet: Fleet) -> None:
    conf = fleet.broker().conf.read_text().splitlines()
    for line in claim_one("docs/collect.md", "text", how="check", index=1).lines():
        assert line in conf, line


def test_the_status_line_is_pymbs() -> None:
    st = CollectStats(messages=84112, rows=6224288, lag=0.3, db_ok=True, mqtt_ok=True)
    line = status_text(st, 70.0, (69.0, 84112 - 1204, 6224288 - 89096))
    assert_shaped(claim_one("docs/collect.md", "text", how="compare", index=2), [line])


def test_the_command_lines_run(fleet: Fleet, postgres: Postgres, tmp_path: Path) -> None:
    broker = fleet.broker()
    (sqlite_line,) = claim_one("docs/collect.md", "sh", how="run", contains="fleet.sqlite").lines()
    shared = claim_one("docs/collect.md", "sh", how="run", contains="--share").lines()
    procs = [_start(sqlite_line, broker.url, postgres.url, tmp_path)]
    procs += [_start(line, broker.url, postgres.url, tmp_path) for line in shared]
    try:
        for p in procs:
            wait_subscribed(p)
        msgs = _samples(20)
        publish(broker.port, msgs)
        wait_rows(lambda: sqlite_count(tmp_path / "fleet.sqlite"), 2 * len(msgs),
                  "the SQLite collector's rows")
        wait_rows(lambda: pg_count(postgres.url), 2 * len(msgs), "the shared collectors' rows")
        errs = [stop(p) for p in procs]
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.communicate(timeout=30)
    assert "fleet.sqlite" in errs[0]
    assert errs[1] == errs[2] == ""  # --quiet
    assert pg_count(postgres.url) == 2 * len(msgs)  # shared: each value once
    latest, retention = claim("docs/collect.md", "sql", how="run")
    with psycopg.connect(postgres.url) as con:
        rows = con.execute(latest.text.encode()).fetchall()
        assert [r[:3] for r in rows] == [(f"board-{b}", "sdm630-1", p) for b in
                                         sorted(str(i) for i in range(20))
                                         for p in ("current_a", "voltage_v")]
        assert {r[4] for r in rows if r[2] == "voltage_v"} == {232.0}
        con.execute(retention.text.encode())
        con.commit()
    assert pg_count(postgres.url) == 2 * len(msgs)  # nothing older than 90 days
