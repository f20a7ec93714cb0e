"""``pymb log`` with many Modbus TCP devices, each its own server: one
``pymb simulate --tcp 127.0.0.1:0 --count N`` process serves N ports, the
configuration has a bus per port (one map device of 10 points each) at a 1 s
interval; every device gets a sample at every slot and none is skipped."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import pytest
from conftest import run_pymb

from pymb.bench.gatebench import TEN_POINTS
from pymb.sim import SimulatorProcess
from pymb.store.mapviews import view_names

TEN = TEN_POINTS  # the 10-point device the gateway bench polls


def _log_many(tmp_path: Path, devices: int, seconds: float) -> None:
    db = tmp_path / "many.sqlite"
    config = tmp_path / "many.toml"
    (tmp_path / "ten.toml").write_text(TEN)
    with SimulatorProcess(["--map", str(tmp_path / "ten.toml"), "ten-floats:1,dynamic=0", "--tcp",
                           "127.0.0.1:0", "--count", str(devices)], quiet=True) as sim:
        ports = sim.tcp_ports
        assert len(ports) == devices
        config.write_text(f'[output]\npath = "{db}"\n' + "".join(
            f'\n[[bus]]\nname = "d{i}"\ntcp = "127.0.0.1:{p}"\ninterval = 1\ntimeout = 0.5\n'
            f'  [[bus.device]]\n  map = "ten.toml"\n  address = 1\n  name = "dev-{i}"\n'
            for i, p in enumerate(ports)))
        r = run_pymb("log", "--config", str(config), "--seconds", str(seconds),
                     timeout=seconds + 120)
    assert r.returncode == 0, r.stderr
    assert "interval slot(s) skipped" not in r.stderr, r.stderr  # the summary's count
    assert "(0 faults)" in r.stderr, r.stderr
    con = sqlite3.connect(db)
    try:
        counts = dict(con.execute("SELECT d.name, count(*) FROM samples s JOIN devices d "
                                  "ON d.id = s.device_id GROUP BY d.id"))
        view = view_names("ten-floats")[0]
        values = set(con.execute(f"SELECT value_0, value_9 FROM {view}"))
    finally:
        con.close()
    assert set(counts) == {f"dev-{i}" for i in range(devices)}
    slots = int(seconds)
    assert all(slots <= n <= slots + 1 for n in counts.values()), counts
    assert values == {(0.5, 9.5)}  # every sample's registers, decoded by the map's view


def test_twenty_tcp_devices_for_ten_seconds_skip_no_slot(tmp_path: Path) -> None:
    _log_many(tmp_path, 20, 10.0)


@pytest.mark.slow
def test_a_hundred_tcp_devices_for_ten_minutes_skip_no_slot(tmp_path: Path) -> None:
    _log_many(tmp_path, 100, 600.0)
