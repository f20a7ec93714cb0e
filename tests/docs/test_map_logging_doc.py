"""docs/cli.md's map-device configuration and docs/storage.md's query for a
map device stay true: the TOML example is shown whole and loads, the keys
the page lists are the keys the loader takes, and the "value at time t"
query runs on a database ``pymb log`` wrote from a simulated meter."""

from __future__ import annotations

import re
import sqlite3
import time
from pathlib import Path

from conftest import run_pymb
from docblocks import claim_one

from pymb.devices.deviceconfig import MAP_DEVICE_KEYS
from pymb.logger import load_config
from pymb.sim import SimulatorProcess

ROOT = Path(__file__).resolve().parents[2]
CLI = (ROOT / "docs" / "cli.md").read_text()
STORAGE = (ROOT / "docs" / "storage.md").read_text()
EXAMPLE = ROOT / "docs" / "examples" / "meters.toml"


def test_the_meters_example_is_shown_whole_and_loads() -> None:
    text = EXAMPLE.read_text()
    section = CLI[CLI.index("### Map devices"):]
    assert claim_one("docs/cli.md", "toml", how="load", index=1).text == text
    cfg = load_config(EXAMPLE)
    devices = cfg.buses[0].devices
    assert not any(d.map.timing.backoff for d in devices)  # offline/retry, not backoff
    main, meter, vfd = devices
    assert (main.type, main.name, main.groups) == ("eastron-sdm630", "main",
                                                     ("fast", "energy", "quality", "config"))
    assert (meter.groups, meter.offline_after, meter.offline_retry) == (("fast",), 2, 10.0)
    assert vfd.name == "generic-vfd-5"
    for key in MAP_DEVICE_KEYS:
        assert f"`{key}`" in section, key


def test_the_value_at_time_t_query_of_the_storage_page(tmp_path: Path) -> None:
    block = claim_one("docs/storage.md", "sh", how="run", contains="sqlite3 meters.sqlite").text
    block = block[:block.index('LIMIT 1"') + len("LIMIT 1")]
    query = re.sub(r"\s+", " ", block.split('"', 1)[1])
    db = tmp_path / "meters.sqlite"
    with SimulatorProcess(["eastron-sdm120:2", "--tcp", "127.0.0.1:0"], quiet=True) as sim:
        r = run_pymb("log", "--tcp", sim.endpoint, "eastron-sdm120:2", "--seconds", "1.2",
                     "--out", str(db), "--quiet")
    assert r.returncode == 0, r.stderr
    con = sqlite3.connect(db)
    before = int(time.time())  # unixepoch('now'): whole seconds
    row = con.execute(query).fetchone()
    after = int(time.time())
    last = "SELECT max(s.time_utc) FROM samples s JOIN devices d ON d.id = s.device_id " \
           "WHERE d.humidity_units = 'group=fast' AND s.time_utc <= ?"
    want = {con.execute(last, (now,)).fetchone()[0] for now in (before, after)}
    (t,) = con.execute("SELECT time_utc FROM eastron_sdm120_readings WHERE time = ?",
                       (row[0],)).fetchone()
    con.close()
    assert row[1] == 230.5  # the simulator's example voltage
    assert t in want
    # and with sqlite3 itself, as the page runs it
    import subprocess
    out = subprocess.run(["sqlite3", str(db), query], capture_output=True, text=True,
                         check=True).stdout
    assert out.strip().endswith("|230.5"), out


def test_the_fleet_page_datatype_table_is_the_code() -> None:
    from pymb.fleet.mapmetrics import datatype
    from pymb.fleet.protobuf import DataType
    from pymb.maps import TYPES, loads

    page = (ROOT / "docs" / "fleet.md").read_text()
    table = page[page.index("| point type | Sparkplug datatype |"):]
    table = table[:table.index("\n\n")]
    names = {"UInt8": DataType.UINT8, "Int8": DataType.INT8, "UInt16": DataType.UINT16,
             "Int16": DataType.INT16, "UInt32": DataType.UINT32, "Int32": DataType.INT32,
             "UInt64": DataType.UINT64, "Int64": DataType.INT64, "Float": DataType.FLOAT,
             "Double": DataType.DOUBLE, "String": DataType.STRING, "Boolean": DataType.BOOLEAN}
    said: dict[str, DataType] = {}
    for row in table.splitlines()[2:]:
        types, kinds = (c.strip() for c in row.strip("| ").split("|"))
        groups = [re.findall(r"`(\w+)`", part) for part in types.split(" / ")]
        for ts, kind in zip(groups, kinds.split(" / "), strict=True):
            for t in ts:
                said[t] = names[kind.strip()]
    assert set(said) >= set(TYPES) - {"scale", "offset"}
    for t in TYPES:
        count = 4 if t == "string" else None
        extra = {"bit": "bit = 0\n", "bits": "shift = 0\nwidth = 3\n"}.get(t, "")
        text = ('schema = "pymb.map/1"\n[device]\nid = "x"\n[[point]]\nname = "p"\n'
                f'address = 0\ntype = "{t}"\n' + (f"count = {count}\n" if count else "")
                + ("count = 2\n" if t == "raw" else "")
                + ('table = "coil"\n' if t == "bool" else "") + extra)
        p = loads(text).points["p"]
        assert datatype(p) == said[t], t
    scaled = loads('schema = "pymb.map/1"\n[device]\nid = "x"\n[[point]]\nname = "p"\n'
                   'address = 0\ntype = "u16"\nscale = 0.1\n').points["p"]
    assert datatype(scaled) == DataType.DOUBLE
    by_sf = loads('schema = "pymb.map/1"\n[device]\nid = "x"\n[[point]]\nname = "p"\n'
                  'address = 0\ntype = "u16"\nscale_from = "sf"\n[[point]]\nname = "sf"\n'
                  'address = 1\ntype = "sunssf"\n').points["p"]
    assert datatype(by_sf) == DataType.DOUBLE
