"""``pymb watch`` of a hub where something else answers: the same rule as
``read`` and ``log``. A read that supplies no value of what was asked for is
a fault whose message names what answers, and the next try waits (0.5 s,
doubling), each try asking the device again."""

from __future__ import annotations

import json
from collections.abc import Iterator

import pytest
from conftest import run_pymb

from pymb.sim import SimulatorProcess


@pytest.fixture(scope="module")
def bus() -> Iterator[str]:
    """A CoolPro at 40 and an old hub (50 channels, no voltage block) at 7, on TCP."""
    sim = SimulatorProcess(["coolpro:40", "hub:7,firmware=1.07", "--tcp", "127.0.0.1:0"],
                           quiet=True).start()
    try:
        yield sim.endpoint
    finally:
        sim.stop()


def _watch(bus: str, *args: str) -> tuple[int, list[dict[str, object]]]:
    done = run_pymb("watch", *args, "--tcp", bus, "--json", timeout=60)
    assert not done.stderr, done.stderr
    return done.returncode, [json.loads(line) for line in done.stdout.splitlines()]


def test_watch_hub_where_a_coolpro_answers(bus: str) -> None:
    rc, lines = _watch(bus, "hub:40", "--count", "3")
    assert rc == 3  # nothing read
    assert [d["attempt"] for d in lines] == [1, 2, 3]
    errors = [str(d["error"]) for d in lines]
    assert all("values" not in d for d in lines)
    for e in errors:
        assert e.startswith(f"no value from hub:40 on {bus}: address 40 answers like a "
                            "CoolPro, not a hub (serial 12345"), e
    assert errors[0].endswith("; next try in 0.5 s")
    assert errors[1].endswith("; next try in 1 s")
    assert "next try" not in errors[2]  # the last of --count: no next try
    # the pauses were kept: 0.5 s, then 1 s
    times = [float(str(d["time_utc"])) for d in lines]
    assert times[1] - times[0] >= 0.5
    assert times[2] - times[1] >= 1.0


def test_watch_blocks_the_firmware_lacks(bus: str) -> None:
    # Only the voltage block, which firmware 1.07 lacks: no value either.
    rc, lines = _watch(bus, "hub:7,channels=50", "--block", "voltage_mv", "--count", "1")
    assert rc == 3
    (line,) = lines
    assert line["error"] == (f"no value from hub:7 on {bus}: address 7 answers like a hub but "
                             "supplied no value (50 channels, firmware V1.07 or below)")
    # With a block it has beside it, the hub's values are shown, the voltages as missing.
    rc, lines = _watch(bus, "hub:7,channels=50", "--block", "temperature_c,voltage_mv",
                       "--count", "2")
    assert rc == 0
    assert [("error" in d) for d in lines] == [False, False]
    values = lines[-1]["values"]
    assert isinstance(values, dict)
    assert any(v is not None for v in values["temperature_c"])
    assert all(v is None for v in values["voltage_mv"])
