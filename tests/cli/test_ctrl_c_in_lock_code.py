"""Ctrl-C landing inside the stdlib's lock code of the main thread's wait
(CPython gh-118433) ends a command as any Ctrl-C does: exit 130, no traceback.

The window is a few bytecodes wide (tests/cli/test_scan_ctrl_c_anywhere.py
hits it for real in ``pymb scan``, which no longer waits in that code); every
other command's main thread that waits on a queue, an event or a thread's
start can still meet it, so the command line takes it as the interrupt it is.
"""

from __future__ import annotations

import argparse
import threading

import pytest

from pymb import cli
from pymb.commands import info


def _released_twice(args: argparse.Namespace) -> int:
    # What Condition.__exit__ raises when the KeyboardInterrupt came before
    # _acquire_restore took the lock back: a second release of a free lock.
    lock = threading.Lock()
    try:
        raise KeyboardInterrupt
    except KeyboardInterrupt:
        lock.release()
    return 0


def _another_runtime_error(args: argparse.Namespace) -> int:
    try:
        raise KeyboardInterrupt
    except KeyboardInterrupt:
        raise RuntimeError("a bug in a cleanup") from None


def test_a_ctrl_c_turned_into_release_unlocked_lock_exits_130(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(info, "run", _released_twice)
    assert cli.main(["info", "nothing.sqlite"]) == cli.EXIT_INTERRUPTED
    out = capsys.readouterr()
    assert "Traceback" not in out.err + out.out


def test_other_runtime_errors_are_not_taken_for_a_ctrl_c(
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(info, "run", _another_runtime_error)
    with pytest.raises(RuntimeError, match="a bug in a cleanup"):
        cli.main(["info", "nothing.sqlite"])
