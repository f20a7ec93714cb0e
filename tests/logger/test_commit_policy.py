"""When the logger commits: when enough samples wait (bytes of registers),
or when the oldest has waited the commit interval (by default, longer for a
small batch); events within a second; and what a configuration may say
about it."""

from __future__ import annotations

import itertools
import time
from pathlib import Path

import pytest

from pymb.errors import InvalidArgument
from pymb.logger import BusConfig, DeviceConfig, LogConfig, Logger, load_config
from pymb.logger.config import COMMIT_INTERVAL, COMMIT_LONGEST, COMMIT_SMALL
from pymb.sim import Simulator
from pymb.store import SqliteSink


class CountingSink(SqliteSink):
    """A SqliteSink that records (monotonic time, samples stored) at each commit
    that had something to commit."""

    def __init__(self, path: Path) -> None:
        super().__init__(path)
        self.commits: list[tuple[float, int]] = []

    def commit(self) -> None:
        had = self.stored
        super().commit()
        if not self.commits or self.commits[-1][1] != had:
            self.commits.append((time.monotonic(), had))


def _run(tmp_path: Path, seconds: float, **cfg: float) -> CountingSink:
    with Simulator(["coolpro"], seed=1) as sim:
        bus = BusConfig("b", sim.port, timeout=1.0, interval=0.01,
                        devices=[DeviceConfig("coolpro", 40)])
        tmp_path.mkdir(exist_ok=True)
        sink = CountingSink(tmp_path / "data.sqlite")
        config = LogConfig([bus], "sqlite", str(tmp_path / "data.sqlite"), **cfg)  # type: ignore[arg-type]
        Logger(config, sink=sink).run(seconds)
    return sink


def test_a_commit_when_enough_bytes_wait(tmp_path: Path) -> None:
    # 10 CoolPro samples (16 bytes of registers each) per commit; no clock.
    sink = _run(tmp_path, 1.5, commit_bytes=160, commit_interval=1000.0)
    counts = [n for _, n in sink.commits]
    steps = [b - a for a, b in zip([0, *counts], counts, strict=False)]
    assert len(steps) >= 3, steps
    assert all(s >= 10 for s in steps[:-1]), steps  # the last: what the stop committed


def test_a_commit_when_the_oldest_has_waited(tmp_path: Path) -> None:
    sink = _run(tmp_path, 2.0, commit_bytes=1 << 30, commit_interval=0.4)
    assert 3 <= len(sink.commits) <= 8, sink.commits


def test_a_small_batch_waits_longer(tmp_path: Path) -> None:
    # By default a batch is committed after commit_default seconds only if it
    # holds commit_small bytes of registers; a smaller one waits up to
    # commit_longest (a page rewritten per commit for a few samples).
    small = _run(tmp_path / "small", 3.5, commit_default=0.3, commit_small=1 << 30,
                 commit_longest=1.0)
    times = [t for t, _ in small.commits[:-1]]  # the last: what the stop committed
    gaps = [b - a for a, b in itertools.pairwise(times)]
    assert len(times) >= 2, small.commits
    assert all(g >= 0.9 for g in gaps), gaps
    big = _run(tmp_path / "big", 2.0, commit_default=0.3, commit_small=16, commit_longest=1.0)
    assert len(big.commits) >= 4, big.commits  # about every 0.3 s: 16 bytes wait at once


def test_an_interval_that_was_set_is_the_one_bound() -> None:
    assert LogConfig([]).commit_rule() == (COMMIT_INTERVAL, COMMIT_SMALL, COMMIT_LONGEST)
    assert LogConfig([], commit_interval=5.0).commit_rule() == (5.0, 0, 5.0)


def test_the_commit_interval_is_configured(tmp_path: Path) -> None:
    assert LogConfig([]).commit_every == COMMIT_INTERVAL
    with pytest.raises(InvalidArgument, match="commit_interval_s must be a positive"):
        LogConfig([], commit_interval=0)
    toml = tmp_path / "log.toml"
    toml.write_text('[output]\npath = "x.sqlite"\ncommit_interval_s = 30\n'
                    '[[bus]]\nport = "/dev/ttyUSB0"\n[[bus.device]]\ntype = "coolpro"\n')
    assert load_config(toml).commit_every == 30.0
