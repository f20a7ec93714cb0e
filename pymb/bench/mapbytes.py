"""Bytes per stored sample of the shipped maps' devices (the bench's
``logger`` section): each group of each map, written as ``pymb log`` writes
it (one sample row, the group's registers once), measured with dbstat."""

from __future__ import annotations

import os
import random
import sqlite3
from array import array
from collections.abc import Callable
from importlib import resources
from typing import Any

from pymb import maps
from pymb.bench.table import Table
from pymb.devices.mapreading import MapReading, group_layout, group_points
from pymb.store import DeviceInfo, Sample, SqliteSink

__all__ = ["MAPS", "compare", "table"]

#: the shipped maps measured
MAPS = ("eastron-sdm120", "eastron-sdm630", "generic-vfd")


def _reading(m: maps.Map, group: str | None, rng: random.Random) -> MapReading:
    regs = array("H")
    for dec in group_layout(m, group):
        regs.extend(rng.getrandbits(16) for _ in range(dec.count))
    return MapReading(m, group, {}, {}, regs)


def compare(where: str, n: int, say: Callable[[str], None],
            first_group_only: bool = False) -> list[dict[str, Any]]:
    """For each group of each of :data:`MAPS` (only its first with
    ``first_group_only``, as ``--quick`` does): ``n`` samples written to a new
    database in ``where``; the BLOB's bytes and the data's pages (samples and
    their time index, dbstat) per sample."""
    rows = []
    rng = random.Random(0)
    for map_id in MAPS:
        m = maps.builtin(map_id)
        text = (resources.files("pymb.maps") / "builtin" / f"{map_id}.toml").read_text()
        for group in list(m.groups)[:1] if first_group_only else m.groups:
            say(f"logger: {map_id} group {group}, {n} samples")
            path = os.path.join(where, f"map-{map_id}-{group}.sqlite")
            sink = SqliteSink(path)
            info = DeviceInfo("bus1", "bench", map_id, 1, map_id, map_source=text)
            for i in range(n):
                sink.write(Sample(info, 1_700_000_000 + i, float(i), _reading(m, group, rng)))
                if i % 200 == 199:
                    sink.commit()
            sink.close()
            con = sqlite3.connect(path)
            try:
                data = con.execute("SELECT COALESCE(SUM(pgsize), 0) FROM dbstat WHERE name IN "
                                   "('samples', 'samples_time')").fetchone()[0]
            finally:
                con.close()
            blob = 2 * sum(d.count for d in group_layout(m, group))
            rows.append({"map": map_id, "group": group, "interval_s": m.groups[group],
                         "points": len(group_points(m, group)), "blob_bytes": blob,
                         "bytes_per_sample": data / n})
            base = os.path.basename(path)
            for name in os.listdir(where):  # the database and what the writer keeps beside it
                if name.startswith(base) or name.startswith("." + base):
                    os.remove(os.path.join(where, name))
    return rows


def table(rows: list[dict[str, Any]]) -> Table:
    """The report's table of :func:`compare`'s rows."""
    return Table(
        "Map devices: bytes per stored sample of the shipped maps",
        "one sample row per group read, the group's registers once (each table from the "
        "group's first register to its last); bytes on disk: samples and their time "
        "index (dbstat) over the samples written",
        ["map", "group", "interval", "points", "registers BLOB", "bytes / sample"],
        [[r["map"], r["group"], f"{r['interval_s']:g} s", str(r["points"]),
          f"{r['blob_bytes']:,} B", f"{r['bytes_per_sample']:,.0f} B"] for r in rows],
        [False, False, True, True, True, True], [])
