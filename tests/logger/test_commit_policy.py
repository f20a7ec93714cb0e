"""When the logger commits: when enough samples wait (bytes of registers),
or when the oldest has waited the commit interval; events within a second;
and what a configuration may say about it."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from pymb.errors import InvalidArgument
from pymb.logger import BusConfig, DeviceConfig, LogConfig, Logger, load_config
from pymb.logger.config import COMMIT_INTERVAL
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


def test_the_commit_interval_is_configured(tmp_path: Path) -> None:
    assert LogConfig([]).commit_every == COMMIT_INTERVAL
    with pytest.raises(InvalidArgument, match="commit_interval_s must be a positive"):
        LogConfig([], commit_interval=0)
    toml = tmp_path / "log.toml"
    toml.write_text('[output]\npath = "x.sqlite"\ncommit_interval_s = 30\n'
                    '[[bus]]\nport = "/dev/ttyUSB0"\n[[bus.device]]\ntype = "coolpro"\n')
    assert load_config(toml).commit_every == 30.0
