"""``pymb log sunspec:1``: an inverter that is not pymb (pysunspec2's
registers served by pymodbus) changes its power's scale factor while pymb
logs it; every stored power follows its scale factor, never 10x wrong, and a
scale factor that is not implemented stores no value."""

from __future__ import annotations

import signal
import subprocess
from pathlib import Path
from typing import Any

from conftest import PYMB, PYMB_ENV
from sunspec_peer import image, serve

from pymb.devices.mapreading import MapReading
from pymb.maps import sunspec
from pymb.store import samples_after

DEVICE: list[tuple[int, dict[str, Any]]] = [(1, {"Mn": "Acme Solar", "Md": "AS-40K"}),
          (103, {"W": 3342, "W_SF": 0, "A": 5000, "A_SF": -2, "PhVphA": 2301, "V_SF": -1})]


def test_logged_power_follows_its_scale_factor(tmp_path: Path) -> None:
    regs = image(DEVICE)
    m = sunspec.discover(lambda a, n: regs[a - 40000:a - 40000 + n]).map(1)
    w = m.points["inverter_three_phase.W"].address
    assert m.points["inverter_three_phase.W_SF"].address == w + 1
    db = tmp_path / "sunspec.sqlite"
    with serve(regs, tmp_path) as server:
        proc = subprocess.Popen([*PYMB, "log", "sunspec:1", "--tcp", f"127.0.0.1:{server.port}",
                                 "--out", str(db), "--quiet"], env=PYMB_ENV,
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        try:
            # discovery (6 requests) and the first polls: 3,342 W (SF 0)
            server.set({}, after=14)
            server.set({w: [3342, 1]})  # 33,420 W: the same register, SF 1
            server.set({}, after=6)
            server.set({w: [3342, 0x8000]})  # the scale factor not implemented
            server.set({}, after=6)
        finally:
            proc.send_signal(signal.SIGTERM)
            _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    powers = []
    for s in samples_after(db, 0, limit=100_000):
        assert isinstance(s.data, MapReading)
        if "inverter_three_phase.W" in s.data.values:
            powers.append(s.data.values["inverter_three_phase.W"])
            assert s.data.values["inverter_three_phase.A"] == 50.0
    assert set(powers) <= {3342, 33420, None}, set(powers)
    # in the order the inverter gave them, each at least once
    changes = [p for i, p in enumerate(powers) if i == 0 or powers[i - 1] != p]
    assert changes == [3342, 33420, None], changes
