"""systemd's notify protocol, against real datagram sockets (no systemd):
the Notifier alone, then ``pymb log`` as systemd would run it (READY=1,
WATCHDOG=1 from the writer loop, STATUS= with the rates, STOPPING=1)."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import pytest
from conftest import wait_until

pytest.register_assert_rewrite("servicekit")
from servicekit import NotifyListener, StderrLines, start_log  # noqa: E402

from pymb.service.notify import Notifier  # noqa: E402
from pymb.sim import SimulatorProcess  # noqa: E402

pytest_plugins = ["servicekit"]  # the coolpro fixture


def test_without_notify_socket_nothing_is_sent() -> None:
    n = Notifier({})
    assert not n.enabled
    assert n.send("READY=1") is False
    n.ready("x")
    n.tick("y")
    assert Notifier({"NOTIFY_SOCKET": "relative/path"}).enabled is False


def test_abstract_socket_gets_ready_status_and_watchdog() -> None:
    name = f"@pymb-test-notify-{os.getpid()}"
    listener = NotifyListener(name)
    try:
        n = Notifier({"NOTIFY_SOCKET": name, "WATCHDOG_USEC": "200000"})
        assert n.enabled
        assert n.watchdog_every == 0.1
        n.ready("starting")
        assert wait_until(lambda: listener.lines(), "READY=1") == ["READY=1", "STATUS=starting"]
        t0 = time.monotonic()
        while time.monotonic() - t0 < 0.35:  # a main loop turning every 10 ms
            n.tick("not yet due")
            time.sleep(0.01)
        pings = [a for a in listener.lines() if a == "WATCHDOG=1"]
        assert 2 <= len(pings) <= 4  # every 0.1 s: half the manager's 0.2 s
        assert "STATUS=not yet due" not in listener.lines()  # at most every 5 s
        n.stopping("bye")
        assert wait_until(lambda: "STOPPING=1" in listener.lines(), "STOPPING=1")
        n.close()
    finally:
        listener.close()


def test_path_socket_and_a_watchdog_meant_for_another_process(tmp_path: Path) -> None:
    where = str(tmp_path / "notify")
    listener = NotifyListener(where)
    try:
        other = Notifier({"NOTIFY_SOCKET": where, "WATCHDOG_USEC": "1000",
                          "WATCHDOG_PID": str(os.getpid() + 1)})
        assert other.watchdog_every is None  # WATCHDOG_PID names someone else
        mine = Notifier({"NOTIFY_SOCKET": where, "WATCHDOG_USEC": "1000",
                         "WATCHDOG_PID": str(os.getpid())})
        mine.reloading()
        mine.tick()
        wait_until(lambda: len(listener.lines()) >= 3, "three messages")
        got = listener.lines()
        assert got[0] == "RELOADING=1"
        assert got[1].startswith("MONOTONIC_USEC=")
        assert got[2] == "WATCHDOG=1"
    finally:
        listener.close()


def test_a_manager_that_went_away_is_ignored(tmp_path: Path) -> None:
    where = str(tmp_path / "gone")
    NotifyListener(where).close()  # bound, then removed
    n = Notifier({"NOTIFY_SOCKET": where})
    assert n.send("READY=1") is False  # no exception


def test_pymb_log_as_a_notify_service(coolpro: SimulatorProcess, tmp_path: Path) -> None:
    name = f"@pymb-test-log-{os.getpid()}"
    listener = NotifyListener(name)
    db = tmp_path / "data.sqlite"
    proc = start_log("--tcp", coolpro.endpoint, "coolpro:40", "--interval", "0.05",
                     "--out", str(db), "--quiet",
                     env={"NOTIFY_SOCKET": name, "WATCHDOG_USEC": "400000"})
    err = StderrLines(proc)
    try:
        wait_until(lambda: "READY=1" in listener.lines(), "READY=1",
                   alive=lambda: proc.poll() is None)
        # WATCHDOG=1 keeps coming from the writer loop (every 0.2 s) and a STATUS=
        # with the samples and the rate follows within STATUS_EVERY (5 s)
        wait_until(lambda: listener.lines().count("WATCHDOG=1") >= 5, "five pings",
                   alive=lambda: proc.poll() is None)
        status = wait_until(lambda: [a for a in listener.lines()
                                     if a.startswith("STATUS=") and "/s" in a
                                     and not a.startswith("STATUS=0 samples")],
                            "a STATUS with samples", 15, alive=lambda: proc.poll() is None)
        assert " samples " in status[-1]
        assert "faults 0" in status[-1]
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(30) == 0, err.text()
        assert wait_until(lambda: "STOPPING=1" in listener.lines(), "STOPPING=1")
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        listener.close()
