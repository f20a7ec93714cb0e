"""--on-change over random hub sweeps (drift, offline channels, blocks the
firmware lacks, fewer than 100 channels) stores exactly the channels that a
plain reading of the rule picks: a state changed, a value moved past its
deadband since the channel was last stored, or its heartbeat came."""

from __future__ import annotations

import random
import sqlite3
from array import array
from pathlib import Path

import pytest

from pymb.devices import HubReading, decode_hub
from pymb.store import DeviceInfo, OnChange, Sample, SqliteSink

BLOCKS = ["temperature_c", "humidity_pct", "pressure_temperature_c", "pressure_kpa",
          "voltage_mv", "rssi_dbm", "temperature2_c"]
BANDS = {"temperature_c": 0.5, "humidity_pct": 1.0, "voltage_mv": 20.0}


def sweeps(rng: random.Random, channels: int, n: int) -> list[tuple[float, HubReading]]:
    regs = array("H", [rng.randrange(100, 400) for _ in range(700)])
    out = []
    t = 0.0
    for _ in range(n):
        for _ in range(rng.randrange(0, 12)):
            i = rng.randrange(7) * 100 + rng.randrange(channels)
            pick = rng.random()
            regs[i] = 0xFFFF if pick < 0.1 else max(0, min(0x7FFF, regs[i] + rng.randint(-9, 9)))
        gone = [b for b in ("voltage_mv", "temperature2_c") if rng.random() < 0.05]
        t += rng.choice([0.5, 1.0, 1.0, 7.0])
        out.append((t, decode_hub(array("H", regs), channels=channels, unsupported=gone)))
    return out


def picked_by_the_rule(steps: list[tuple[float, HubReading]], channels: int,
                       heartbeat: float) -> list[list[int]]:
    last: dict[int, list[tuple[float, int]]] = {}
    due: dict[int, float] = {}
    out = []
    for t, r in steps:
        got = []
        for ch in range(channels):
            now = [(r.values[b * channels + ch], r.raw_states[b * channels + ch])
                   for b in range(7)]
            old = last.get(ch)
            store = old is None or t >= due[ch] or any(
                s != os_ or (s == 0 and abs(v - ov) > BANDS.get(BLOCKS[b], 0.0))
                for b, ((v, s), (ov, os_)) in enumerate(zip(now, old, strict=True)))
            if store:
                last[ch], due[ch] = now, t + heartbeat
                got.append(ch + 1)
        if got:
            out.append(got)
    return out


@pytest.mark.parametrize(("seed", "channels"), [(1, 100), (2, 50), (3, 7)])
def test_on_change_stores_the_channels_the_rule_picks(tmp_path: Path, seed: int,
                                                       channels: int) -> None:
    steps = sweeps(random.Random(seed), channels, 60)
    db = tmp_path / "oc.sqlite"
    sink = SqliteSink(db, on_change=OnChange(20.0, BANDS))
    hub = DeviceInfo("b", "p", "hub", 1, "hub-1", channels)
    for t, r in steps:
        sink.write(Sample(hub, 1_800_000_000.0 + t, t, r))
    sink.close()
    with sqlite3.connect(db) as con:
        rows = con.execute("SELECT sample_id, channel FROM hub_changes ORDER BY sample_id, "
                           "channel").fetchall()
    stored: dict[int, list[int]] = {}
    for sid, ch in rows:
        stored.setdefault(sid, []).append(ch)
    want = picked_by_the_rule(steps, channels, 20.0)
    assert list(stored.values()) == want
    assert 2 < len(want) < len(steps)  # some sweeps stored nothing, some channels moved


METER = '''schema = "pymb.map/1"
[device]
id = "meter"
table = "holding"
[[point]]
name = "energy_wh"
address = 0
type = "u32"
kind = "counter"
deadband = 100
[[point]]
name = "power_w"
address = 2
type = "u16"
'''


def test_a_counter_that_goes_back_is_stored_within_its_deadband(tmp_path: Path) -> None:
    """A map device's counter (kind counter) is stored past its deadband and
    whenever it goes back (a reset), however little; the rule the CoolPro's
    uptime follows."""
    from pymb import maps
    from pymb.devices.mapreading import MapReading

    m = maps.loads(METER)
    db = tmp_path / "m.sqlite"
    sink = SqliteSink(db, on_change=OnChange(600.0))
    info = DeviceInfo("b", "p", "meter", 1, "meter-1", map_source=METER)
    steps = [(0.0, 1000, True), (1.0, 1050, False), (2.0, 1101, True), (3.0, 1090, True),
             (4.0, 1091, False)]
    for t, wh, _ in steps:
        r = MapReading(m, None, {"energy_wh": wh, "power_w": 7},
                       {"energy_wh": "value", "power_w": "value"},
                       array("H", [wh >> 16, wh & 0xFFFF, 7]))
        sink.write(Sample(info, 1_800_000_000.0 + t, t, r))
    sink.close()
    with sqlite3.connect(db) as con:
        stored = [t for (t,) in con.execute("SELECT monotonic FROM samples ORDER BY id")]
    assert stored == [t for t, _, keep in steps if keep]
