"""``pymb bench --sections serve --quick``: reads direct and through ``pymb
serve`` (plain and TLS) with their latencies and serve's CPU per read; the
report shows them and the full run judges the two targets."""

from __future__ import annotations

import json

import pytest

from pymb.bench import report, servebench
from pymb.cli import main


def test_serve_section(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "--quick", "--only", "pymb", "--sections", "serve", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    s = result["serve"]
    assert [r["way"] for r in s["rows"]] == [
        "direct (pymb RtuClient)", "through pymb serve", "through pymb serve, TLS"]
    for r in s["rows"]:
        assert r["reads"] == 300
        assert 0 < r["p50_us"] <= r["p99_us"]
    assert s["serve_cpu_us"] > 0
    assert s["serve_cpu_tls_us"] > 0
    # one round (--quick): the median of one ratio, that round's TLS / plain
    assert len(s["tls_cpu_x_rounds"]) == 1
    assert s["tls_cpu_x"] == pytest.approx(s["serve_cpu_tls_us"] / s["serve_cpu_us"], rel=0.02)
    p = s["pipelined"]
    assert [r["max_inflight"] for r in p["rows"]] == [1, 8]
    for r in p["rows"]:
        assert r["reads"] == 8 * 40
        assert r["reads_per_s"] > 0
        assert 0 < r["p50_us"] <= r["p99_us"]
    assert p["speedup_x"] == pytest.approx(
        p["rows"][1]["reads_per_s"] / p["rows"][0]["reads_per_s"], rel=0.02)
    md = report.to_markdown(result)
    assert "pymb serve --tcp: requests in flight to a Modbus TCP device" in md
    assert "pymb serve: a telemetry read direct and through pymb serve" in md
    assert "latency added by pymb serve, p99" in md
    judged = servebench.targets(s)
    assert [t[0] for t in judged] == ["pymb serve: latency added, p99",
                                      "pymb serve: CPU per read, TLS / plain"]
    assert all(t[4] is not None for t in judged)
