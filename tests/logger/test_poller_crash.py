"""A poller that dies on an exception is a bug in pymb: ``pymb log`` does not
go on with that bus silently unpolled, nor report a clean run. The run stops,
what was read is kept, the summary names the bus in one line, the traceback
goes to stderr (a bug, not a user mistake) and the exit code is 70
(EX_SOFTWARE). The bug is injected into a real ``pymb log`` process; the
other bus is served by ``pymb simulate`` over TCP."""

from __future__ import annotations

import sqlite3
import subprocess
import sys
from pathlib import Path

from conftest import PYMB_ENV

from pymb.sim import SimulatorProcess

#: ``pymb log`` whose poller of the bus named "broken" raises once the other
#: bus has logged a sample (it waits for that counter, at most 30 s); that bus
#: is RTU over TCP, polled by a thread of its own (map devices on plain TCP
#: share the one loop of pymb.logger.tcploop)
DRIVER = '''
import sys, time
from pymb.logger import poller
connect = poller.BusPoller._connect
def _connect(self):
    if self.bus.name != "broken":
        return connect(self)
    deadline = time.monotonic() + 30
    while self.stats.samples == 0 and time.monotonic() < deadline:
        time.sleep(0.01)
    raise RuntimeError("injected: a bug in the poller")
poller.BusPoller._connect = _connect
from pymb.cli import main
sys.exit(main(sys.argv[1:]))
'''


def test_a_poller_that_dies_ends_the_run_with_exit_70(tmp_path: Path) -> None:
    db = tmp_path / "crash.sqlite"
    config = tmp_path / "log.toml"
    with SimulatorProcess(["eastron-sdm120:1", "--tcp", "127.0.0.1:0"], quiet=True) as sim:
        config.write_text(f'''[output]
path = "{db}"
[[bus]]
name = "good"
tcp = "{sim.endpoint}"
[[bus.device]]
type = "eastron-sdm120"
address = 1
[[bus]]
name = "broken"
rtu_over_tcp = "127.0.0.1:1"
[[bus.device]]
type = "eastron-sdm120"
address = 2
''')
        # --seconds 600: the run ends by itself, long before, or the timeout fails it
        r = subprocess.run([sys.executable, "-c", DRIVER, "log", "--config", str(config),
                            "--seconds", "600", "--quiet"], env=PYMB_ENV,
                           capture_output=True, text=True, timeout=120, check=False)
    assert r.returncode == 70, r.stderr
    assert "Traceback" in r.stderr  # a bug: its traceback, on stderr
    assert "RuntimeError: injected: a bug in the poller" in r.stderr
    # the summary's one line, and not "never opened" for the bus that failed
    assert r.stderr.splitlines()[-1] == (
        "pymb log: bus broken stopped on an internal error (a bug in pymb): "
        "RuntimeError: injected: a bug in the poller"), r.stderr
    assert "never opened" not in r.stderr
    assert "delivered no sample" not in r.stderr
    con = sqlite3.connect(db)
    try:
        (kept,) = con.execute("SELECT COUNT(*) FROM samples s JOIN devices d "
                              "ON d.id = s.device_id WHERE d.name = 'eastron-sdm120-1'"
                              ).fetchone()
    finally:
        con.close()
    assert kept >= 1  # what the good bus read before the stop is kept
