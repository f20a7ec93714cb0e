"""A device of ``[device.timing] backoff = true`` polled on a serial line:
the points it refuses while it answers the others are counted as
``unsupported`` in the run's summary, each once, as for any map device
(docs/cli.md); only a poll in which it refused every point is a failure.
Real ``pymb log`` processes against ``pymb simulate`` on a pty."""

from __future__ import annotations

from pathlib import Path

from conftest import run_pymb

from pymb.sim import SimulatorProcess

SERVED = '''schema = "pymb.map/1"
[device]
id = "test-meter"
table = "input"
[device.timing]
backoff = true
[[point]]
name = "voltage_v"
address = 0
type = "f32"
unit = "V"
example = 230.5
'''


def test_a_backoff_device_counts_the_point_it_refuses(tmp_path: Path) -> None:
    (tmp_path / "served.toml").write_text(SERVED)
    (tmp_path / "meter.toml").write_text(SERVED + '''[[point]]
name = "missing_a"
address = 100
type = "f32"
''')
    db = tmp_path / "u.sqlite"
    with SimulatorProcess(["--map", str(tmp_path / "served.toml"), "test-meter:1"],
                          quiet=True) as sim:
        r = run_pymb("log", "--map", str(tmp_path / "meter.toml"), "--port", sim.port,
                     "test-meter:1", "--seconds", "0.5", "--out", str(db))
    assert r.returncode == 0, r.stderr
    assert "test-meter-1: 1 point(s) unsupported, " in r.stderr, r.stderr
    assert "failed poll" not in r.stderr, r.stderr


def test_a_hub_counts_the_blocks_its_firmware_lacks(tmp_path: Path) -> None:
    db = tmp_path / "h.sqlite"
    with SimulatorProcess(["hub:7,firmware=1.07"], quiet=True) as sim:
        r = run_pymb("log", "--port", sim.port, "hub:7,channels=50", "--seconds", "1",
                     "--out", str(db))
    assert r.returncode == 0, r.stderr
    assert "hub-7: 5 point(s) unsupported, " in r.stderr, r.stderr
