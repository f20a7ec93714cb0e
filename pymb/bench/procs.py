"""Child processes of the bench: simulators and contender workers.

Every child gets ``PR_SET_PDEATHSIG`` (SIGTERM when the bench dies, even by
SIGKILL), its stderr goes to a file (shown when it fails, never mixed into
the table), and every exchange with it has a deadline. :class:`Children`
stops them all, newest first, on the way out of a ``with`` block: normal
end, error or Ctrl-C.
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
from types import TracebackType

__all__ = ["ROOT", "Child", "ChildError", "Children", "SimChild", "python_env"]

_PR_SET_PDEATHSIG = 1


def _die_with_parent() -> None:  # runs in the child between fork and exec
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
    except (OSError, AttributeError):
        pass


#: the directory holding the pymb package this bench runs from
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def python_env() -> dict[str, str]:
    """The environment for ``python -m pymb...`` children: this pymb first
    on the path (a source checkout works without installing)."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (ROOT, env.get("PYTHONPATH")) if p)
    return env


class ChildError(Exception):
    """A child failed, answered ``err``, or missed its deadline."""


class Child:
    """A child process speaking one line per request and per answer."""

    def __init__(self, name: str, argv: Sequence[str], *, env: dict[str, str] | None = None,
                 stdin: bool = True) -> None:
        self.name = name
        self.argv = list(argv)
        # Closed in stop(): the file outlives this call on purpose.
        self._log = tempfile.TemporaryFile(prefix="pymb-bench-")  # noqa: SIM115
        self.proc = subprocess.Popen(
            self.argv, stdin=subprocess.PIPE if stdin else subprocess.DEVNULL,
            stdout=subprocess.PIPE, stderr=self._log, env=env or python_env(),
            # `python -m` puts the working directory first on sys.path: start
            # where this pymb lives, so no other checkout's pymb is picked up.
            cwd=ROOT,
            # Own session: the terminal's Ctrl-C reaches the bench only, which
            # then stops its children in order.
            preexec_fn=_die_with_parent, start_new_session=True,
        )
        self._buf = b""

    @property
    def pid(self) -> int:
        """The child's process id."""
        return self.proc.pid

    def stderr_tail(self, limit: int = 1500) -> str:
        """The end of what the child wrote on stderr."""
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

    def stop(self) -> None:
        """Ask politely (close stdin, SIGTERM), then SIGKILL; safe twice."""
        proc = self.proc
        if proc.poll() is None:
            if proc.stdin is not None:
                with contextlib.suppress(OSError):
                    proc.stdin.close()
            try:
                proc.wait(1.0)
            except subprocess.TimeoutExpired:
                proc.terminate()
                try:
                    proc.wait(3.0)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
        for f in (proc.stdin, proc.stdout):
            if f is not None:
                with contextlib.suppress(OSError):
                    f.close()
        with contextlib.suppress(OSError):
            self._log.close()


class SimChild(Child):
    """``python -m pymb simulate ARGS`` (what :class:`pymb.sim.SimulatorProcess`
    runs), with its stderr kept out of the table; :attr:`port` is the
    pseudo-terminal it printed."""

    def __init__(self, args: Sequence[str]) -> None:
        super().__init__("simulator " + " ".join(args),
                         [sys.executable, "-m", "pymb", "simulate", *args], stdin=False)
        self.args = list(args)
        self.port = ""

    def wait_ready(self, timeout: float = 20.0) -> SimChild:
        """Wait for the endpoint line."""
        self.port = self.readline(timeout).strip()
        if not self.port.startswith("/"):
            raise ChildError(f"{self.name}: printed {self.port!r}, not a port")
        return self

    def stop(self) -> None:
        """SIGTERM (the simulator's clean stop), then SIGKILL."""
        proc = self.proc
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(5.0)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        super().stop()


class Children:
    """Owns children; stops every one on exit, newest first."""

    def __init__(self) -> None:
        self._children: list[Child] = []

    def add(self, child: Child) -> Child:
        """Take ``child`` into care."""
        self._children.append(child)
        return child

    def sims(self, args_list: Sequence[Sequence[str]], timeout: float = 30.0) -> list[SimChild]:
        """Start simulators side by side and wait until each serves."""
        sims = [SimChild(a) for a in args_list]
        self._children.extend(sims)
        for s in sims:
            s.wait_ready(timeout)
        return sims

    def stop(self, child: Child) -> None:
        """Stop one child now."""
        child.stop()
        with contextlib.suppress(ValueError):
            self._children.remove(child)

    def stop_all(self) -> None:
        """Stop every child, newest first."""
        while self._children:
            child = self._children.pop()
            with contextlib.suppress(Exception):
                child.stop()

    def __enter__(self) -> Children:
        return self

    def __exit__(self, et: type[BaseException] | None, ev: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.stop_all()
