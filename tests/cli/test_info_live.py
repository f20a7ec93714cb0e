"""``pymb info`` as a new user runs it, beside a ``pymb log`` that is running:
it says that a logger is writing the file and how old the newest committed
sample is, lists every polling group of a map device (one that never
delivered a sample too, with 0) and no phantom group for the events of a
device. The device is a scripted Modbus TCP gateway (tests/hostile_gateway.py):
the "fast" group's register answers, the "slow" group's answers exception 04
(a device failure) every time."""

from __future__ import annotations

import json
import re
import signal
import socket
import subprocess
import time
from pathlib import Path

from conftest import PYMB, PYMB_ENV, run_pymb
from dbwait import wait_for
from hostile_gateway import Hostile, Request, good

MAP = '''schema = "pymb.map/1"
[device]
id = "grouped-meter"
table = "holding"
[groups]
fast = { interval = 0.2 }
slow = { interval = 0.2 }
[[point]]
name = "a"
address = 0
type = "u16"
group = "fast"
[[point]]
name = "b"
address = 100
type = "u16"
group = "slow"
'''


def _script(n: int, req: Request, conn: socket.socket) -> bytes:
    tid, unit, fc, address, _ = req
    if address == 100:
        return tid.to_bytes(2, "big") + b"\x00\x00\x00\x03" + bytes((unit, fc | 0x80, 0x04))
    return good(*req)


def test_info_of_a_live_log_says_who_writes_and_every_group(tmp_path: Path) -> None:
    (tmp_path / "meter.toml").write_text(MAP)
    db = tmp_path / "live.sqlite"
    gw = Hostile(_script)
    proc = subprocess.Popen([*PYMB, "log", "--map", str(tmp_path / "meter.toml"), "--tcp",
                             f"127.0.0.1:{gw.port}", "grouped-meter:1", "--out", str(db),
                             "--quiet", "--commit-interval", "0.5"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=PYMB_ENV)
    try:
        wait_for(db, "SELECT COUNT(*) FROM samples", at_least=3, proc=proc)
        wait_for(db, "SELECT COUNT(*) FROM events WHERE kind = 'exception'", proc=proc)
        r = run_pymb("info", str(db))
        assert r.returncode == 0, r.stderr
        line = next(ln for ln in r.stdout.splitlines() if ln.startswith("  writer "))
        assert f"pymb log, PID {proc.pid} is writing it" in line, r.stdout
        age = re.search(r"the newest committed sample is ([\d.]+) s old", line)
        assert age, line
        assert 0 <= float(age.group(1)) < 60, line
        doc = json.loads(run_pymb("info", str(db), "--json").stdout)
        assert doc["writer"] == f"pymb log, PID {proc.pid}"
        assert 0 <= doc["newest_age_s"] < 60
    finally:
        proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=60)
        gw.close()
    assert proc.returncode == 0
    r = run_pymb("info", str(db))
    assert r.returncode == 0, r.stderr
    assert re.search(r"\n  writer      none: no logger writes it now; the newest committed "
                     r"sample is [\d.]+ s old\n", r.stdout), r.stdout
    (dev,) = [ln for ln in r.stdout.splitlines() if ln.startswith("    grouped-meter-1 ")]
    assert re.search(r": (\d+) samples \(\1 fast, 0 slow\), ", dev), dev
    assert "all points" not in r.stdout
    doc = json.loads(run_pymb("info", str(db), "--json").stdout)
    assert doc["writer"] is None
    (d,) = doc["devices"]
    assert d["groups"] == {"fast": d["samples"], "slow": 0}
    assert 0 < doc["newest_age_s"] <= time.time() - doc["last"] + 1
