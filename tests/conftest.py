"""What the whole test suite shares: one root, one subprocess environment,
one timeout, and the fixtures more than one file uses.

The helpers here are imported by name (``from conftest import ROOT``): the
tests directory is on the path, as it is for peers.py and reference.py.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TypeVar

import pytest

from pymb.sim import SimClock, Simulator

_T = TypeVar("_T")

#: The source checkout: ``python -m pymb`` children run this pymb.
ROOT = Path(__file__).resolve().parents[1]

#: The environment of a ``python -m pymb`` child: this checkout first on the path.
PYMB_ENV = dict(os.environ, PYTHONPATH=os.pathsep.join(
    p for p in (str(ROOT), os.environ.get("PYTHONPATH")) if p))

#: The ``pymb`` command as a user runs it (with PYMB_ENV): ``[*PYMB, "log", ...]``.
PYMB = [sys.executable, "-m", "pymb"]

#: A client's reply timeout where a test waits for one to pass: short, so the
#: suite stays fast; longer under valgrind or qemu (PYMB_TEST_TIMEOUT).
TIMEOUT = float(os.environ.get("PYMB_TEST_TIMEOUT", "0.25"))


#: SIGINT's disposition when the suite started: ``signal.SIG_IGN`` when a
#: non-interactive shell, ``nohup`` or a CI runner started it in the background.
SIGINT_AT_START = signal.getsignal(signal.SIGINT)
#: SIGHUP's disposition when the suite started: ``signal.SIG_IGN`` under ``nohup``.
SIGHUP_AT_START = signal.getsignal(signal.SIGHUP)


def pytest_configure(config: pytest.Config) -> None:
    """Every child starts with SIGINT at its default, as from a terminal.

    An ignored signal stays ignored across ``exec``, so a suite started with
    SIGINT ignored would start children that rightly ignore Ctrl-C, and the
    Ctrl-C tests would wait for nothing. A handled signal is reset to its
    default by ``exec``: the suite's own process handles SIGINT by doing
    nothing (it still ignores it, as it was asked to), and every launcher,
    ours or a library's, starts its children with SIGINT at its default.
    SIGHUP likewise (``nohup``): the terminal-closed and reload tests test
    pymb, not the shell that started the suite.
    """
    if SIGINT_AT_START is signal.SIG_IGN:
        signal.signal(signal.SIGINT, _ignore)
    if SIGHUP_AT_START is signal.SIG_IGN:
        signal.signal(signal.SIGHUP, _ignore)


def _ignore(signum: int, frame: Any) -> None:
    """SIGINT or SIGHUP in the suite's own process when it started ignored: nothing."""


def rss_kb(pid: int | None = None) -> int:
    """Resident memory (VmRSS, kB) of process ``pid``, this one by default."""
    with open(f"/proc/{pid or 'self'}/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("VmRSS"))


def open_fds(pid: int | None = None) -> int:
    """How many descriptors process ``pid`` (this one by default) has open."""
    return len(os.listdir(f"/proc/{pid or 'self'}/fd"))


@pytest.fixture
def frozen_clock() -> SimClock:
    """A simulator clock frozen at 1000 s: time moves only by ``advance()``."""
    clock = SimClock(start=1000.0)
    clock.freeze()
    return clock


def wait_until(event: Callable[[], _T], what: str | Callable[[], str], timeout: float = 10.0,
               *, alive: Callable[[], bool] | None = None, every: float = 0.02) -> _T:
    """Poll ``event()`` until it is true and return what it returned: the one
    way a test waits for something to happen (a counter, a row, a state).

    Fails naming ``what`` (a text, or a function that says what was seen)
    after ``timeout`` seconds, or at once when ``alive()`` (the thing that
    should make the event happen: a process, a thread) turns false first.
    """
    deadline = time.monotonic() + timeout
    while True:
        got = event()
        if got:
            return got
        said = what() if callable(what) else what
        if alive is not None and not alive():
            raise AssertionError(f"stopped before {said}")
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout:g} s waiting for {said}")
        time.sleep(every)


def run_pymb(*args: str, timeout: float = 120, **kw: Any) -> subprocess.CompletedProcess[str]:
    """Run ``pymb ARGS`` to the end as a user does (this checkout, PYMB_ENV
    unless ``env`` is given); stdout and stderr are captured as text."""
    kw.setdefault("env", PYMB_ENV)
    done: subprocess.CompletedProcess[str] = subprocess.run(
        [*PYMB, *args], capture_output=True, text=True, timeout=timeout, check=False, **kw)
    return done


@pytest.fixture
def sim3() -> Iterator[Simulator]:
    """A CoolPro, a 100-channel hub and a 50-channel hub (firmware 1.07)."""
    with Simulator(["coolpro", "hub:250", "hub:7,firmware=1.07"], seed=3) as s:
        yield s


@pytest.fixture(scope="module")
def logged(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A database ``pymb log`` wrote from a CoolPro and a hub (1.5 s)."""
    db = tmp_path_factory.mktemp("logged") / "data.sqlite"
    with Simulator(["coolpro", "hub:250"], seed=3) as s:
        r = run_pymb("log", "coolpro:40", "hub:250", "--port", s.port, "--seconds", "1.5",
                     "--out", str(db), "--quiet")
    assert r.returncode == 0, r.stderr
    return db
