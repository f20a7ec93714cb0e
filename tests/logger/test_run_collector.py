"""The garbage collector during a ``pymb log`` run: what existed at the start is
frozen out of its passes and the young generation is large while the run
lasts, and both are as they were once it ends."""

from __future__ import annotations

import gc
import socket
import threading
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


def test_two_runs_that_end_out_of_order_give_the_collector_back(tmp_path: Path) -> None:
    """Two loggers in one process: the first to start ends first, and the
    collector is as it was once both have ended (not left as the second
    found it, in the first one's run)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    loggers = []
    for name in ("a", "b"):
        (tmp_path / f"{name}.toml").write_text(
            f'[output]\npath = "{tmp_path / (name + ".sqlite")}"\n'
            f'[[bus]]\nname = "m"\ntcp = "127.0.0.1:{port}"\n'
            '[[bus.device]]\ntype = "eastron-sdm120"\n')
        loggers.append(Logger(load_config(tmp_path / f"{name}.toml")))
    first, second = loggers
    before = gc.get_threshold(), gc.get_freeze_count()
    first_running, second_running = threading.Event(), threading.Event()
    first.tick = lambda _l, _t, final: None if final else first_running.set()
    second.tick = lambda _l, _t, final: None if final else second_running.set()

    def stop_first() -> None:
        # the first runs until the second one is under way, then ends (the second runs on)
        assert first_running.wait(60)
        assert second_running.wait(60)
        first.stop()

    stopper = threading.Thread(target=stop_first)
    stopper.start()
    done = threading.Event()

    def run_first_logger() -> None:
        first.run(60)
        done.set()

    runner = threading.Thread(target=run_first_logger)
    runner.start()
    try:
        assert first_running.wait(60)

        def second_stop() -> None:
            assert done.wait(60)  # the first one has ended
            second.stop()

        ender = threading.Thread(target=second_stop)
        ender.start()
        second.run(60)
        ender.join(60)
    finally:
        first.stop()
        stopper.join(60)
        runner.join(60)
    assert (gc.get_threshold(), gc.get_freeze_count()) == before
