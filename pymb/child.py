"""pymb's one child-process launcher: the simulators the demo, the benchmark
and the tests start, and the benchmark's contender workers.

A :class:`Child` runs ``python -m pymb...`` (or any program) with this pymb
first on its path, in its own session (the terminal's Ctrl-C reaches the
parent only, which then stops its children in order), with
``PR_SET_PDEATHSIG`` (SIGTERM when the parent dies, even by SIGKILL). Its
stderr goes to a file (shown when it fails), to the parent's stderr, or
nowhere; every line read from it has a deadline; :meth:`Child.stop` asks
politely (closes stdin, SIGTERM) before SIGKILL.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import select
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from typing import IO, Protocol

__all__ = ["ROOT", "Child", "ChildError", "Process", "pymb_argv", "pymb_argv_here", "python_env"]

_PR_SET_PDEATHSIG = 1

#: the directory holding the pymb package this process runs from
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _die_with_parent() -> None:  # runs in the child between fork and exec
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
    except (OSError, AttributeError):
        pass


def python_env() -> dict[str, str]:
    """The environment for ``python -m pymb...`` children: this pymb first
    on the path (a source checkout works without installing)."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (ROOT, env.get("PYTHONPATH")) if p)
    return env


def pymb_argv(*args: str) -> list[str]:
    """``python -m pymb ARGS`` with this interpreter."""
    return [sys.executable, "-m", "pymb", *args]


def pymb_argv_here(*args: str) -> list[str]:
    """``python -P -m pymb ARGS``, for a child started in the caller's folder
    (where relative paths mean what they say): ``-P`` keeps that folder off
    the path, so a clone's source tree there (its ``pymb/`` without the
    built extension) never shadows this pymb."""
    return [sys.executable, "-P", "-m", "pymb", *args]


class ChildError(RuntimeError):
    """A child failed, answered ``err``, or missed its deadline."""


class Process(Protocol):
    """What :class:`Child` uses of its process (a :class:`subprocess.Popen`)."""

    pid: int
    stdin: IO[bytes] | None
    stdout: IO[bytes] | None
    returncode: int | None

    def poll(self) -> int | None: ...
    def wait(self, timeout: float | None = None) -> int: ...
    def terminate(self) -> None: ...
    def kill(self) -> None: ...


class Child:
    """A child process that speaks in lines on stdout.

    ``stderr``: ``"file"`` keeps it in a temporary file (:meth:`stderr_tail`),
    ``"inherit"`` shares the parent's, ``"drop"`` discards it. ``cwd``: where
    the child starts (the default, :data:`ROOT`, makes ``python -m`` find
    this pymb before any other in the working directory).
    """

    def __init__(self, name: str, argv: Sequence[str], *, env: dict[str, str] | None = None,
                 stdin: bool = True, stderr: str = "file", cwd: str | None = ROOT) -> None:
        self.name = name
        self.argv = list(argv)
        # Closed in stop(): the file outlives this call on purpose.
        self._log: IO[bytes] | None = (
            tempfile.TemporaryFile(prefix="pymb-child-")  # noqa: SIM115
            if stderr == "file" else None)
        err: IO[bytes] | int | None = (self._log if self._log is not None else
                                       subprocess.DEVNULL if stderr == "drop" else None)
        self.proc: Process = self._launch(stdin, err, env or python_env(), cwd)
        self._buf = b""

    def _launch(self, stdin: bool, err: IO[bytes] | int | None, env: dict[str, str],
                cwd: str | None) -> Process:
        """Start the process: ``argv`` in its own session, dying with this one."""
        return subprocess.Popen(
            self.argv, stdin=subprocess.PIPE if stdin else subprocess.DEVNULL,
            stdout=subprocess.PIPE, stderr=err, env=env, cwd=cwd,
            preexec_fn=_die_with_parent, start_new_session=True,
        )

    @property
    def pid(self) -> int:
        """The child's process id."""
        return self.proc.pid

    def stderr_tail(self, limit: int = 1500) -> str:
        """The end of what the child wrote on stderr (when kept in a file)."""
        if self._log is None:
            return ""
        try:
            self._log.seek(0)
            text = self._log.read().decode(errors="replace").strip()
        except (OSError, ValueError):
            return ""
        return text[-limit:]

    def readline(self, timeout: float) -> str:
        """The next line from the child, within ``timeout`` seconds."""
        assert self.proc.stdout is not None
        fd = self.proc.stdout.fileno()
        deadline = time.monotonic() + timeout
        while b"\n" not in self._buf:
            left = deadline - time.monotonic()
            if left <= 0:
                raise ChildError(f"{self.name}: no answer within {timeout:g} s")
            r, _, _ = select.select([fd], [], [], left)
            if not r:
                continue
            chunk = os.read(fd, 65536)
            if not chunk:
                code = self.proc.poll()
                tail = self.stderr_tail()
                raise ChildError(f"{self.name} exited (code {code})"
                                 + (f": {tail}" if tail else ""))
            self._buf += chunk
        line, _, self._buf = self._buf.partition(b"\n")
        return line.decode()

    def ask(self, command: str, timeout: float) -> str:
        """Send one command line and return the answer after ``ok``;
        raises :class:`ChildError` on ``err`` or silence."""
        assert self.proc.stdin is not None
        try:
            self.proc.stdin.write(command.encode() + b"\n")
            self.proc.stdin.flush()
        except (BrokenPipeError, OSError):
            raise ChildError(f"{self.name} is gone: {self.stderr_tail()}") from None
        return self.expect_ok(timeout)

    def expect_ok(self, timeout: float) -> str:
        """Read one answer line: return what follows ``ok``."""
        line = self.readline(timeout)
        head, _, rest = line.partition(" ")
        if head == "ok":
            return rest
        if head == "err":
            raise ChildError(f"{self.name}: {rest}")
        raise ChildError(f"{self.name}: unexpected answer {line[:200]!r}")

    def stop(self, *, grace: float = 1.0, term_wait: float = 3.0) -> int | None:
        """Close stdin and wait ``grace`` seconds (a child reading stdin then
        ends by itself), then SIGTERM and wait ``term_wait``, then SIGKILL;
        returns the exit code. Safe to call twice."""
        proc = self.proc
        if proc.poll() is None:
            if proc.stdin is not None:
                with contextlib.suppress(OSError):
                    proc.stdin.close()
                with contextlib.suppress(subprocess.TimeoutExpired):
                    proc.wait(grace)
            if proc.poll() is None:
                proc.terminate()
                try:
                    proc.wait(term_wait)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
        for f in (proc.stdin, proc.stdout):
            if f is not None:
                with contextlib.suppress(OSError):
                    f.close()
        if self._log is not None:
            with contextlib.suppress(OSError):
                self._log.close()
        return proc.returncode
