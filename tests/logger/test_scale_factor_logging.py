"""A SunSpec-style inverter whose scale factor changes while ``pymb log``
polls it: a scripted Modbus TCP responder (not pymb's simulator) raises
``W_SF`` from 0 to 1 (above 32,767 W), then says it is not implemented
(0x8000). Every stored sample must hold W = raw x 10^W_SF of that very read,
or no value (``no_scale``): never 3,342 W for 33,420 W."""

from __future__ import annotations

import csv
import io
import sqlite3
from pathlib import Path

from conftest import run_pymb
from peerkit import Reply
from peers import TcpPeer

from pymb.devices.mapreading import MapReading
from pymb.store import samples_after

INVERTER = '''schema = "pymb.map/1"
[device]
id = "sunspec-103"
[groups]
fast = { interval = 0.1 }
[[point]]
name = "W"
address = 40083
type = "i16"
scale_from = "W_SF"
unit = "W"
group = "fast"
[[point]]
name = "W_SF"
address = 40084
type = "sunssf"
[[point]]
name = "inverter.Hz"
address = 40085
type = "u16"
scale = 0.01
group = "fast"
'''


def test_stored_watts_follow_the_scale_factor_read_with_them(tmp_path: Path) -> None:
    (tmp_path / "inverter.toml").write_text(INVERTER)
    db = tmp_path / "inv.sqlite"
    peer = TcpPeer()
    mem = peer.memory.holding
    mem[40083:40086] = [3342, 0, 5000]
    reads = 0

    def hook(slave: int, pdu: bytes, normal: bytes | None) -> Reply | None:
        nonlocal reads
        if pdu[:3] == bytes((3, 40083 >> 8, 40083 & 0xFF)):
            reads += 1
            if reads == 3:  # 33,420 W: the raw value stays, the scale factor goes to 1
                mem[40084] = 1
            elif reads == 6:
                mem[40084] = 0x8000
        return None

    peer.hook = hook
    with peer:
        r = run_pymb("log", "--map", str(tmp_path / "inverter.toml"), "--tcp",
                     f"127.0.0.1:{peer.port}", "sunspec-103:1", "--seconds", "4",
                     "--out", str(db), "--quiet")
    assert r.returncode == 0, r.stderr
    assert reads >= 8, reads
    samples = samples_after(db, 0, limit=1000)
    seen = []
    for s in samples:
        assert isinstance(s.data, MapReading)
        v, st = s.data.values, s.data.states
        assert set(v) == {"W", "inverter.Hz", "W_SF"}  # the SF is read and stored with W
        assert v["inverter.Hz"] == 50.0
        sf = v["W_SF"]
        if sf is None:
            assert (v["W"], st["W"], st["W_SF"]) == (None, "no_scale", "not_implemented")
        else:
            assert isinstance(sf, int)
            assert v["W"] == 3342.0 * 10 ** sf, v
        seen.append(v["W"])
    # in the device's order: 3,342 W, then 33,420 W, then no value
    assert seen[:3] == [3342.0] * 3
    assert seen[3:6] == [33420.0] * 3
    assert seen[6:]
    assert all(w is None for w in seen[6:])
    # a model's own names (W, a dotted prefix) go through export and the SQL views
    wide = run_pymb("export", str(db), "--csv", "-", "--layout", "wide")
    assert wide.returncode == 0, wide.stderr
    rows = list(csv.DictReader(io.StringIO(wide.stdout)))
    assert [r["W"] for r in rows[:4]] == ["3342.0", "3342.0", "3342.0", "33420.0"]
    assert rows[0]["inverter.Hz"] == "50.0"
    con = sqlite3.connect(db)
    try:
        got = con.execute('SELECT "W", "W_SF", "inverter.Hz" FROM sunspec_103_readings '
                          "ORDER BY sample_id").fetchall()
    finally:
        con.close()
    assert got[0] == (3342.0, 0, 50.0)
    assert got[3] == (33420.0, 1, 50.0)
    assert got[-1] == (None, None, 50.0)
