"""``pymb bench --sections writes --quick``: a write command's latency over
MQTT while the logger polls simulated Modbus TCP devices, beside the wire
time of the write and its read back (run as a user runs it)."""

from __future__ import annotations

import json

from conftest import run_pymb


def test_the_writes_section_measures_commands_and_the_wire() -> None:
    r = run_pymb("bench", "--sections", "writes", "--quick", "--only", "pymb", "--json",
                 timeout=300)
    assert r.returncode == 0, r.stderr
    w = json.loads(r.stdout)["writes"]
    assert w["status"] == "ok", w
    assert w["devices"] == 10
    assert w["commands"] == 20  # every command answered
    assert 0 < w["p50_s"] <= w["p99_s"] < 10
    assert 0 < w["wire_p50_s"] <= w["wire_p99_s"]
    assert isinstance(w["goal_met"], bool)
    text = run_pymb("bench", "--sections", "writes", "--quick", "--only", "pymb", timeout=300)
    assert "command to result" in text.stdout
    assert "wire: write + read back" in text.stdout
