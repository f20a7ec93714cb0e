"""``pymb bench --sections gateway``: every design polls the same simulated TCP
devices and stores every poll; the tables and targets come from one result.
No timing assertions: the figures are the bench's."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from pymb.bench import gatebench, report
from pymb.bench.gateworker import DESIGNS, GateSink
from pymb.cli import main


def test_the_gateway_section_runs_every_design(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "--quick", "-q", "--json", "--only", "pymb", "--sections",
                 "gateway"]) == 0
    result: dict[str, Any] = json.loads(capsys.readouterr().out)
    rows = result["gateway"]["rows"]
    # --quick: the target's workload at 10 devices (a full run: both workloads at
    # 10, 100 and 300); the designs, then the logger itself: a bus per device, one
    # loop for all
    want = [("SDM630", 10, d) for d in (*DESIGNS, *gatebench.LOG_DESIGNS)]
    assert [(r["workload"], r["devices"], r["design"]) for r in rows] == want
    for r in rows:
        if r["design"] == "pymodbus" and r["status"] == "skipped":
            assert r["reason"]
            continue
        assert r["status"] == "ok", r
        assert r["samples"] > 0
        assert r["checked"] is True  # the stored registers decode to what the device holds
        assert r["values_per_poll"] == {"10 points": 10, "SDM630": 74}[r["workload"]]
        assert r["requests"] == (9 if r["workload"] == "SDM630" else 1)
        assert r["cpu_s"] > 0
        assert r["rss_kb"] > 0
        threads = r["threads"]
        if r["design"] == "threads":
            assert threads >= r["devices"]  # one per connection
        elif r["design"] in gatebench.LOG_DESIGNS:
            assert threads == 2  # the writer and the one loop, whatever the devices
        else:
            assert threads < 5  # one loop (and the worker's two helpers)
    titles = [t.title for t in report.tables(result)]
    assert any(t.startswith("Gateway: many Modbus TCP devices") for t in titles)


def _row(design: str, devices: int, values: float, rss_mb: float) -> dict[str, Any]:
    return {"workload": "SDM630", "devices": devices, "design": design, "status": "ok",
            "values_per_cpu_s": values, "rss_kb": rss_mb * 1024}


def test_the_targets_take_the_worst_pipelined_row_and_the_most_devices() -> None:
    section = {"rows": [_row("fanout-pipelined", 10, 2e6, 30), _row("fanout-pipelined", 300,
                                                                   9e5, 59),
                        _row("fanout", 300, 5e6, 61), _row("threads", 300, 9e9, 99)]}
    (values, logged, rss) = gatebench.targets(section)
    assert values[2] == 9e5
    assert values[4] is False
    assert logged[2] is None  # no pymb log row measured
    assert rss[2] == 61  # the fan-out rows at 300 devices; the thread design is not pymb's
    assert rss[4] is False
    section["rows"] = section["rows"][:2]
    (values, logged, rss) = gatebench.targets(section)
    assert rss[2] == 59
    assert rss[4] is True
    section["rows"] += [_row("pymb-log-pipelined", 10, 1.2e6, 40),
                        _row("pymb-log-pipelined", 300, 1.1e6, 58)]
    (values, logged, rss) = gatebench.targets(section)
    assert logged[2] == 1.1e6
    assert logged[4] is True
    assert rss[2] == 59


def test_pymb_log_at_100_devices_and_at_the_rate_plants_poll_have_targets_of_their_own() -> None:
    rows = [_row("pymb-log-pipelined", 10, 3e6, 40), _row("pymb-log-pipelined", 100, 2.4e6, 45),
            {**_row("pymb-log-1s", 100, 4e5, 52), "workload": gatebench.RATE_WORKLOADS[0],
             "cpu_per_value_us": 2.5},
            {**_row("pymb-log-1s", 100, 2.9e6, 290), "workload": gatebench.RATE_WORKLOADS[1],
             "cpu_per_value_us": 0.34}]
    (_, _, rss, at100, rate, peers) = gatebench.targets({"rows": rows})
    assert rss[2] == 45  # the at-rate rows are not the gateway's device counts
    assert at100[1:] == (">= 2,500,000", 2.4e6, "values/s", False)  # the 100-device row only
    assert rate[1:] == ("<= 5", 2.5, "us", True)
    assert peers[1:] == (">= 3,000,000", 2.9e6, "values/s", False)
    rows[3] = {**rows[3], "status": "failed"}
    assert gatebench.targets({"rows": rows})[5][2:] == (None, "values/s", None)


def test_a_row_that_measured_nothing_prints_as_a_dash() -> None:
    row = {**_row("pymb-log", 300, 0, 40), "values_per_cpu_s": None, "cpu_per_poll_us": None,
           "samples": 0, "wall_s": 3.0, "threads": 301, "checked": True}
    (table,) = gatebench.tables({"warmup": 1.0, "seconds": 3.0, "rows": [row]})
    assert table.rows[0][3:5] == ["-", "-"]


def test_the_sink_stores_every_sample_of_a_batch_in_order(tmp_path: Path) -> None:
    # 150 rows: two INSERTs of 64 and one of the 22 left; then a batch of one
    sink = GateSink(str(tmp_path / "gate.db"), warmup=0.0, seconds=60.0)
    batch = [(t, t % 7, bytearray(t.to_bytes(2, "big") * 3)) for t in range(150)]
    sink(batch)
    sink(batch[:1])
    rows = sink.db.execute("SELECT t, device, registers FROM sample ORDER BY rowid").fetchall()
    assert rows == [(t, d, bytes(r)) for t, d, r in [*batch, batch[0]]]
    assert sink.stored == 151
    sink.db.close()
