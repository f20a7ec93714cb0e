"""The bench's bytes per stored sample of the shipped maps: every group of
each, its BLOB the group's registers as the logger stores them."""

from __future__ import annotations

from pathlib import Path

from pymb import maps
from pymb.bench.mapbytes import MAPS, compare
from pymb.devices.mapreading import group_layout
from pymb.store import PAGE_SIZE


def test_every_group_of_each_shipped_map_is_measured(tmp_path: Path) -> None:
    rows = compare(str(tmp_path), 400, lambda _: None)
    assert [(r["map"], r["group"]) for r in rows] == [
        (i, g) for i in MAPS for g in maps.builtin(i).groups]
    for r in rows:
        m = maps.builtin(r["map"])
        assert r["blob_bytes"] == 2 * sum(d.count for d in group_layout(m, r["group"]))
        assert r["points"] > 0
        # a row is at least its BLOB; the rest is the row's header and its time
        # index entry (under 120 bytes), and the pages' slack: a page wastes
        # less than one row, so a row costs under row * page / (page - row)
        row = r["blob_bytes"] + 120
        assert r["blob_bytes"] <= r["bytes_per_sample"] < row * PAGE_SIZE / (PAGE_SIZE - row), r
    assert not list(tmp_path.iterdir())  # its databases are removed
