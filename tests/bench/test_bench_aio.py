"""``pymb bench --sections aio``: pymb.aio beside the blocking calls and
pymodbus's async client, per call and in the event loop's lag; the tables
and the target come from one result. No timing assertions here: the lag
bound is tests/aio/test_aio_lag.py's, the figures are the bench's."""

from __future__ import annotations

import json
from typing import Any

import pytest

from pymb.bench import aiobench, report
from pymb.cli import main


def test_the_aio_section_measures_every_stack(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "--quick", "-q", "--json", "--only", "pymb", "--sections", "aio"]) == 0
    result: dict[str, Any] = json.loads(capsys.readouterr().out)
    aio = result["aio"]
    for workload in ("hub", "telemetry"):
        rows = {r["name"]: r for r in aio[workload]["rows"]}
        assert list(rows) == ["pymb", "pymb-aio", "pymodbus-async"]
        assert aio[workload]["baseline"] == "pymb"
        for r in rows.values():
            if r["name"] == "pymodbus-async" and r["status"] == "skipped":
                assert r["reason"]
                continue
            assert r["status"] == "ok", r
            assert r["wall_us"] > 0
            assert r["cpu_us"] > 0
            assert r["wall_x"] > 0
        assert rows["pymb"]["wall_x"] == 1.0
    lag = aio["lag"]["rows"]
    # --quick: the emulated line only (a full run adds the line without emulation)
    assert [(r["stack"], r["line"]) for r in lag] == [
        (s, "emulated 115200")
        for s in ("pymb-aio", "pymodbus-async", "blocking-in-loop", "ticker-alone")]
    for r in lag:
        assert r["status"] == "ok" or (r["stack"] == "pymodbus-async" and r["reason"]), r
        if r["status"] == "ok":
            assert r["hubs"] == 8
            assert all(run["ticks"] > 0 and min(run["sweeps"]) > 0 for run in r["runs"])
            assert 0 <= r["p50_ms"] <= r["p99_ms"] <= r["max_ms"]
    titles = [t.title for t in report.tables(result)]
    assert any(t.startswith("asyncio: per call") for t in titles)
    assert any(t.startswith("asyncio: event loop lag") for t in titles)
    assert "pymb.aio" in report.to_markdown(result)


def test_the_lag_target_is_judged_on_the_wire_bound_pymb_aio_row() -> None:
    def row(stack: str, line: str, p99: float) -> dict[str, Any]:
        return {"stack": stack, "line": line, "status": "ok", "p99_ms": p99}

    section = {"lag": {"rows": [row("pymb-aio", "emulated 115200", 3.0),
                                row("pymodbus-async", "emulated 115200", 9.0),
                                row("pymb-aio", "no emulation", 12.0)]}}
    [(what, goal, measured, unit, met)] = aiobench.targets(section)
    assert (goal, measured, unit, met) == ("<= 5 ms", 3000.0, "us", True)
    assert "8 pymb.aio hubs" in what
    section["lag"]["rows"][0]["p99_ms"] = 6.0
    assert aiobench.targets(section)[0][-1] is False
    section["lag"]["rows"][0]["status"] = "failed"
    assert aiobench.targets(section)[0][2:] == (None, "us", None)
