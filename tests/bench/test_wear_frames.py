"""The SD wear bench's count of the WAL frames each commit wrote, against
a real SQLite writer: two hub sweeps a commit write five pages (the two
sweeps', their parent, the header, the time index's leaf), and a
checkpoint's reset of the WAL (a new salt, frames from the start again)
is followed."""

from __future__ import annotations

import time
from array import array
from pathlib import Path

from pymb.bench.wear import WalFrames
from pymb.devices import decode_hub
from pymb.store import DeviceInfo, Sample, SqliteSink

HUB = DeviceInfo("b", "/dev/null", "hub", 1, "hub-1")


def _commit_sweeps(sink: SqliteSink, start: int, n: int) -> None:
    t0 = time.time() - 10_000
    for i in range(start, start + n):
        regs = array("H", [(i * 13 + k) & 0x7FFF for k in range(700)])
        sink.write(Sample(HUB, t0 + i, float(i), decode_hub(regs)))
    sink.commit()


def test_frames_per_commit_of_two_hub_sweeps_across_a_checkpoint(tmp_path: Path) -> None:
    db = tmp_path / "wear.sqlite"
    sink = SqliteSink(db)
    try:
        for i in range(5):  # the b-trees past their first pages
            _commit_sweeps(sink, 2 * i, 2)
        frames = WalFrames(str(db))
        frames.count()
        frames.frames = frames.commits = 0
        for i in range(5, 25):
            _commit_sweeps(sink, 2 * i, 2)
            frames.count()
        assert frames.commits == 20
        assert frames.frames == 5 * 20
        sink.db.execute("PRAGMA wal_checkpoint(FULL)")  # the next commit resets the WAL
        for i in range(25, 35):
            _commit_sweeps(sink, 2 * i, 2)
            frames.count()
        assert frames.commits == 30
        assert 5 * 30 - 2 <= frames.frames <= 5 * 30 + 2  # a new index or parent page: one more
    finally:
        sink.close()
