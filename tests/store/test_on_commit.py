"""The store's on-commit hook: called after each commit with the highest
sample id then durable, which another connection to the file already sees;
at commit, at close and where a size limit commits within a batch."""

from __future__ import annotations

import sqlite3
import time
from array import array
from pathlib import Path

from pymb.devices import decode_hub
from pymb.store import DeviceInfo, Sample, SqliteSink

HUB = DeviceInfo("b", "/dev/null", "hub", 1, "hub-1")
REGS = array("H", range(700))


def _seen_by_another_connection(db: Path) -> int:
    other = sqlite3.connect(db)
    try:
        return int(other.execute("SELECT COALESCE(MAX(id), 0) FROM samples").fetchone()[0])
    finally:
        other.close()


def test_each_commit_calls_the_hook_with_the_max_id_already_durable(tmp_path: Path) -> None:
    db = tmp_path / "log.sqlite"
    sink = SqliteSink(db)
    calls: list[tuple[int, int]] = []  # (the id given, the id another connection sees)
    sink.on_commit(lambda top: calls.append((top, _seen_by_another_connection(db))))
    t0 = time.time()
    for batch in range(3):
        for i in range(4):
            sink.write(Sample(HUB, t0 + i, float(i), decode_hub(REGS)))
        assert len(calls) == batch  # not before the commit
        sink.commit()
    assert calls == [(4, 4), (8, 8), (12, 12)]
    sink.write(Sample(HUB, t0, 0.0, decode_hub(REGS)))
    sink.close()  # commits what is pending: the hook too
    assert calls[-1] == (13, 13)


def test_every_hook_is_called_in_order(tmp_path: Path) -> None:
    sink = SqliteSink(tmp_path / "log.sqlite")
    order: list[str] = []
    sink.on_commit(lambda top: order.append(f"a{top}"))
    sink.on_commit(lambda top: order.append(f"b{top}"))
    sink.write(Sample(HUB, time.time(), 0.0, decode_hub(REGS)))
    sink.commit()
    sink.close()
    assert order == ["a1", "b1", "a1", "b1"]


def test_a_commit_within_a_batch_under_a_size_limit_calls_the_hook(tmp_path: Path) -> None:
    db = tmp_path / "small.sqlite"
    sink = SqliteSink(db, max_bytes=1_000_000)
    calls: list[tuple[int, int]] = []
    sink.on_commit(lambda top: calls.append((top, _seen_by_another_connection(db))))
    t0 = time.time()
    n = 0
    while not calls and n < 5000:  # bounded: a quarter of the WAL budget comes long before
        sink.write(Sample(HUB, t0 + n, float(n), decode_hub(REGS)))
        n += 1
    assert calls, "no commit within the batch"
    top, seen = calls[0]
    assert 0 < top <= n
    assert seen == top
    sink.close()
