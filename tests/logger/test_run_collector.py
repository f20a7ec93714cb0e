"""The garbage collector during a ``pymb log`` run: what existed at the start is
frozen out of its passes and the young generation is large while the run
lasts, and both are as they were once it ends."""

from __future__ import annotations

import gc
import socket
from pathlib import Path

from pymb.logger import Logger
from pymb.logger.config import load_config


def test_a_run_quiets_the_collector_and_gives_it_back(tmp_path: Path) -> None:
    with socket.socket() as s:  # a port nothing listens on: the bus retries
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    (tmp_path / "log.toml").write_text(
        f'[output]\npath = "{tmp_path / "x.sqlite"}"\n'
        f'[[bus]]\nname = "m"\ntcp = "127.0.0.1:{port}"\n'
        '[[bus.device]]\ntype = "eastron-sdm120"\n')
    before = gc.get_threshold(), gc.get_freeze_count()
    during: list[tuple[int, int]] = []
    logger = Logger(load_config(tmp_path / "log.toml"))

    def tick(_: Logger, __: float, final: bool) -> None:
        if not final:  # (the last one comes after the run)
            during.append((gc.get_threshold()[0], gc.get_freeze_count()))

    logger.tick = tick
    logger.run(1.2)
    assert during, "the run's status callback never ran"
    assert all(young >= 10_000 and frozen > 0 for young, frozen in during)
    assert (gc.get_threshold(), gc.get_freeze_count()) == before
