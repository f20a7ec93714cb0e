"""When the logger commits: when enough samples wait (bytes of registers),
or when the oldest has waited the commit interval (by default 1.5 s, at
any rate); events within a second; and what a configuration may say about
it."""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path

import pytest

from pymb.errors import InvalidArgument
from pymb.logger import BusConfig, DeviceConfig, LogConfig, Logger, load_config
from pymb.logger.config import COMMIT_INTERVAL
from pymb.sim import Simulator
from pymb.store import Sample, SqliteSink


class CountingSink(SqliteSink):
    """A SqliteSink that records (monotonic time, samples stored) at each commit
    that had something to commit."""

    def __init__(self, path: Path) -> None:
        super().__init__(path)
        self.commits: list[tuple[float, int]] = []
        #: at each commit that had samples: how long the oldest had waited since its read
        self.waited: list[float] = []
        self._oldest: float | None = None

    def write_batch(self, samples: Sequence[Sample]) -> None:
        if samples and self._oldest is None:
            self._oldest = min(s.monotonic for s in samples)
        super().write_batch(samples)

    def write(self, sample: Sample) -> None:
        if self._oldest is None:
            self._oldest = sample.monotonic
        super().write(sample)

    def commit(self) -> None:
        had = self.stored
        super().commit()
        if self._oldest is not None:
            self.waited.append(time.monotonic() - self._oldest)
            self._oldest = None
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


def test_by_default_a_slow_log_commits_each_sample_within_the_interval(
        tmp_path: Path) -> None:
    """A few samples a second (a slow log: the old rule kept them for up to
    30 minutes) are committed at the latest COMMIT_INTERVAL after their read:
    what a power cut or a kill loses, and how old a reader's newest sample is."""
    with Simulator(["coolpro"], seed=1) as sim:
        bus = BusConfig("b", sim.port, timeout=1.0, interval=0.5,
                        devices=[DeviceConfig("coolpro", 40)])
        sink = CountingSink(tmp_path / "data.sqlite")
        Logger(LogConfig([bus], "sqlite", str(tmp_path / "data.sqlite")), sink=sink).run(8.0)
    waited = sink.waited[:-1]  # the last: what the stop committed
    assert len(waited) >= 3, sink.waited
    # the interval, plus a turn of the writer's loop and a sync on a loaded machine
    assert max(waited) <= COMMIT_INTERVAL + 0.4, waited


def test_an_interval_that_was_set_is_the_one_bound() -> None:
    assert COMMIT_INTERVAL <= 1.5
    assert LogConfig([]).commit_every == COMMIT_INTERVAL
    assert LogConfig([], commit_interval=5.0).commit_every == 5.0


def test_the_commit_interval_is_configured(tmp_path: Path) -> None:
    assert LogConfig([]).commit_every == COMMIT_INTERVAL
    with pytest.raises(InvalidArgument, match="commit_interval_s must be a positive"):
        LogConfig([], commit_interval=0)
    toml = tmp_path / "log.toml"
    toml.write_text('[output]\npath = "x.sqlite"\ncommit_interval_s = 30\n'
                    '[[bus]]\nport = "/dev/ttyUSB0"\n[[bus.device]]\ntype = "coolpro"\n')
    assert load_config(toml).commit_every == 30.0
