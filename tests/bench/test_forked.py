"""``--quick``'s children forked from the bench's process (pymb.bench.forked):
they run their module as ``python -m`` would, in a session of their own,
with their own stdio and none of the parent's other files, and stop and
report their exit code as a started child does."""

from __future__ import annotations

import os
import sqlite3
import sys
from pathlib import Path

import pytest

from pymb import RtuClient
from pymb.bench.forked import Forked, can_fork, fork_safe, holds_no_file
from pymb.bench.procs import ChildError, Children, ForkedChild
from pymb.devices import CoolPro


def test_only_pymb_modules_of_this_python_are_forked() -> None:
    assert can_fork([sys.executable, "-m", "pymb", "simulate", "hub"])
    assert can_fork([sys.executable, "-m", "pymb.bench.worker", "pymb"])
    assert can_fork([sys.executable, "-m", "pymb", "log", "--out", "x.sqlite"])
    assert not can_fork(["/usr/bin/python3", "-m", "pymb", "simulate"])
    assert not can_fork([sys.executable, "-m", "pymodbus"])
    assert not can_fork([sys.executable, "-m", "pymb.no_such_module", "x"])
    assert not can_fork(["/bin/cat"])


def test_a_child_that_opens_a_database_is_not_forked_while_the_bench_holds_one(
        tmp_path: Path) -> None:
    """SQLite's table of open files goes with a fork: a child opening a file
    with the inode number of one the parent holds meets the parent's locks."""
    log = [sys.executable, "-m", "pymb", "log", "--out", "x.sqlite"]
    sim = [sys.executable, "-m", "pymb", "simulate", "hub"]
    assert fork_safe(log) == holds_no_file()
    con = sqlite3.connect(tmp_path / "held.sqlite")
    con.execute("CREATE TABLE t(x)")
    try:
        assert not holds_no_file()
        assert not fork_safe(log)
        assert fork_safe(sim)  # the simulator opens no database: forked all the same
    finally:
        con.close()


def test_a_forked_simulator_serves_and_stops_with_sigterm() -> None:
    with Children(fork=True) as children:
        (sim,) = children.sims([["coolpro:40,gap=0,baud=115200", "--seed", "0"]])
        assert isinstance(sim.proc, Forked)
        assert os.getsid(sim.pid) == sim.pid  # a session of its own
        with RtuClient(sim.port, 115200, timeout=2.0) as client:
            assert len(CoolPro(client, 40).read_telemetry().registers) > 0
        children.stop(sim)
        assert sim.proc.returncode is not None


def test_a_forked_worker_answers_and_gets_only_what_it_was_given(tmp_path: Path) -> None:
    held = open(tmp_path / "held", "w")  # noqa: SIM115 - open across the fork on purpose
    try:
        # the ticker alone: a worker with no line, answering on stdin
        worker = ForkedChild("w", [sys.executable, "-m", "pymb.bench.aioworker", "lag",
                                   "ticker-alone", "115200"], cwd=str(tmp_path))
        assert isinstance(worker.proc, Forked)
        assert worker.readline(30.0) == "ready"
        proc = Path(f"/proc/{worker.pid}")
        assert os.readlink(proc / "cwd") == str(tmp_path)
        files = {os.readlink(proc / "fd" / n) for n in os.listdir(proc / "fd")}
        assert str(tmp_path / "held") not in files  # the parent's open file is not its
        assert os.getsid(worker.pid) == worker.pid
        assert "p99_ms" in worker.ask("run 0.1", 30.0)
        assert worker.stop() == 0  # stdin closed: it ends by itself
    finally:
        held.close()


def test_other_programs_are_started_as_before() -> None:
    child = ForkedChild("cat", ["/bin/cat"])
    assert not isinstance(child.proc, Forked)
    assert child.ask("ok yes", 10.0) == "yes"
    assert child.stop() == 0


def test_a_forked_child_that_fails_says_why() -> None:
    child = ForkedChild("bad", [sys.executable, "-m", "pymb.bench.worker", "no-such"])
    with pytest.raises(ChildError, match="exited"):
        child.readline(30.0)
    assert child.stop() not in (0, None)
