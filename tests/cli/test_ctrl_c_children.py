"""Children of the suite start with SIGINT at its default, however the suite
was started: the Ctrl-C tests test pymb, not the shell that ran them.

A non-interactive shell, ``nohup`` or a CI runner may start the suite with
SIGINT ignored; conftest then handles SIGINT in the suite's own process (by
doing nothing), so ``exec`` gives every child SIGINT at its default.
``.ci/run`` runs the ``ctrl_c`` tests once more that way, with
PYMB_TEST_SIGINT_IGNORED=1.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import PYMB_ENV, ROOT, SIGINT_AT_START


def _ignored(pid: int) -> bool:
    """Whether process ``pid`` ignores SIGINT (its SigIgn mask, /proc)."""
    with open(f"/proc/{pid}/status") as f:
        mask = next(int(line.split()[1], 16) for line in f if line.startswith("SigIgn:"))
    return bool(mask >> (signal.SIGINT - 1) & 1)


@pytest.mark.ctrl_c
def test_a_child_starts_with_sigint_at_its_default() -> None:
    if os.environ.get("PYMB_TEST_SIGINT_IGNORED") == "1":
        # the run was started as a background job is, and it still ignores Ctrl-C
        assert SIGINT_AT_START is signal.SIG_IGN
        os.kill(os.getpid(), signal.SIGINT)
    proc = subprocess.Popen([sys.executable, "-c",
                             "import sys; print('up', flush=True); sys.stdin.read()"],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        # past the interpreter's start-up: a Ctrl-C inside `site` is a fatal
        # start-up error (exit 1), not the default handler's end
        assert proc.stdout is not None
        assert proc.stdout.readline() == "up\n"
        assert not _ignored(proc.pid)
        proc.send_signal(signal.SIGINT)
        assert proc.wait(30) == -signal.SIGINT  # ended by it, as from a terminal
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(30)


@pytest.mark.ctrl_c
def test_a_suite_started_with_sigint_ignored_too(tmp_path: Path) -> None:
    # The suite as a background job of a non-interactive shell starts it: SIGINT
    # ignored, in a session of its own (no terminal's Ctrl-C reaches it).
    bash, setsid = shutil.which("bash"), shutil.which("setsid")
    assert bash
    assert setsid
    here = Path(__file__).relative_to(ROOT)
    done = subprocess.run(
        [bash, "-c", f"trap '' INT; exec {setsid} --wait \"$@\"", "bash", sys.executable,
         "-m", "pytest", "-q", "-p", "no:cacheprovider", f"{here}::"
         "test_a_child_starts_with_sigint_at_its_default"],
        cwd=ROOT, env={**PYMB_ENV, "PYMB_TEST_SIGINT_IGNORED": "1"}, capture_output=True,
        text=True, timeout=120, check=False)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "1 passed" in done.stdout
