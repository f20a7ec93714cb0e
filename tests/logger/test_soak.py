"""The soak run: the logger at full speed against both simulators with faults
switched on (including unplug episodes) for PYMB_SOAK_SECONDS (default 30
minutes); the logger's resident memory and open descriptors must stay flat.

    PYMB_SOAK_SECONDS=1800 .venv/bin/python -m pytest -m slow tests/logger/test_soak.py -s
"""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import time
from pathlib import Path

import pytest
from conftest import PYMB, PYMB_ENV, open_fds, rss_kb

from pymb.sim import SimulatorProcess


@pytest.mark.slow
def test_soak(tmp_path: Path) -> None:
    seconds = float(os.environ.get("PYMB_SOAK_SECONDS", "1800"))
    # Stable paths (--link), as /dev/serial/by-id/ names are for real adapters:
    # an unplugged pty comes back under another /dev/pts number.
    sims = [
        SimulatorProcess(["coolpro", "--link", str(tmp_path / "psu.tty"), "--seed", "1",
                          "--fault", "bad_crc:0.005",
                          "--fault", "no_reply:0.002", "--fault", "late:0.001,delay=0.3",
                          "--fault", "stray:0.002", "--fault", "unplug:0.0003,seconds=2"]),
        SimulatorProcess(["hub", "--link", str(tmp_path / "hub.tty"), "--seed", "2",
                          "--fault", "busy:0.02",
                          "--fault", "truncate:0.002", "--fault", "wrong_address:0.002",
                          "--fault", "sensor:0.01"]),
    ]
    db = tmp_path / "soak.sqlite"
    cfg = tmp_path / "soak.toml"
    for s in sims:
        s.start()
    try:
        cfg.write_text(f"""
[output]
path = "{db}"
max_mb = 200

[[bus]]
name = "psu"
port = "{sims[0].port}"
timeout = 0.2
[[bus.device]]
type = "coolpro"
address = 40

[[bus]]
name = "sensors"
port = "{sims[1].port}"
timeout = 0.5
[[bus.device]]
type = "hub"
address = 1
""")
        proc = subprocess.Popen([*PYMB, "log", "--config", str(cfg)],
                                env=PYMB_ENV,
                                stderr=subprocess.PIPE, text=True)
        warmup = min(60.0, seconds / 5)
        points: list[tuple[float, int, int]] = []
        t0 = time.monotonic()
        try:
            while (elapsed := time.monotonic() - t0) < seconds:
                time.sleep(min(10.0, max(1.0, seconds / 60)))
                assert proc.poll() is None, "the logger died"
                points.append((elapsed, rss_kb(proc.pid), open_fds(proc.pid)))
        finally:
            proc.send_signal(signal.SIGTERM)
            _, err = proc.communicate(timeout=60)
            assert proc.returncode == 0, err
    finally:
        for s in sims:
            s.stop()
    settled = [p for p in points if p[0] >= warmup]
    rss = [p[1] for p in settled]
    fds = [p[2] for p in settled]
    con = sqlite3.connect(db)
    kept = con.execute("SELECT COUNT(*) FROM samples").fetchone()[0]
    events = dict(con.execute("SELECT kind, COUNT(*) FROM events GROUP BY kind").fetchall())
    assert con.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    con.close()
    summary = next(line for line in err.splitlines() if line.startswith("logged "))
    print(f"\nsoak: {seconds:.0f} s; {summary}; {kept} samples kept under max_mb = 200, "
          f"db {db.stat().st_size / 1e6:.0f} MB; events kept {events}; RSS after warm-up "
          f"{min(rss)}..{max(rss)} kB, fds {min(fds)}..{max(fds)}")
    assert db.stat().st_size < 230e6  # the size limit holds
    assert max(fds) - min(fds) <= 2
    assert max(rss) - rss[0] < 8 * 1024  # flat: no growth beyond allocator noise
    assert events.get("reconnect", 0) >= 1 or seconds < 600
