"""What the command-line tests share: a ``pymb`` process on its own
pseudo-terminal, the Ctrl-C bound, and the checks for no traceback and an
untouched file."""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import os
import pty
import select
import signal
import struct
import subprocess
import termios
import time
from pathlib import Path

import pyte
from conftest import PYMB, PYMB_ENV

#: Ctrl-C must end a command within 0.5 s; the tests allow this much on a
#: loaded 2-core machine (the measured figure is printed with -s).
STOP_BOUND = 0.5 * float(os.environ.get("PYMB_TIMING_SLACK", "3"))


def no_traceback(r: subprocess.CompletedProcess[str]) -> None:
    assert "Traceback" not in r.stderr, r.stderr
    assert "Traceback" not in r.stdout, r.stderr


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


class Pty:
    """A ``pymb`` process on its own pseudo-terminal of a given size."""

    def __init__(self, args: list[str], cols: int = 80, rows: int = 24) -> None:
        self.master, slave = pty.openpty()
        fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", rows, cols, 0, 0))
        self.proc = subprocess.Popen([*PYMB, *args], stdin=slave, stdout=slave, stderr=slave,
                                     env=PYMB_ENV, close_fds=True, start_new_session=True)
        os.close(slave)
        self.out = b""

    def read_until(self, pattern: bytes, timeout: float = 30.0) -> bool:
        """Read output until ``pattern`` shows (True) or ``timeout`` passes."""
        return self.read_more(pattern, 1 - min(1, self.out.count(pattern)), timeout)

    def read_more(self, pattern: bytes, n: int = 1, timeout: float = 30.0) -> bool:
        """Read output until ``pattern`` has shown ``n`` more times (a status
        line or a screen redrawn): True, or False once ``timeout`` passes."""
        want = self.out.count(pattern) + n
        deadline = time.monotonic() + timeout
        while self.out.count(pattern) < want and time.monotonic() < deadline:
            r, _, _ = select.select([self.master], [], [], 0.1)
            if r:
                try:
                    self.out += os.read(self.master, 65536)
                except OSError:
                    break
        return self.out.count(pattern) >= want

    def interrupt(self, sig: int = signal.SIGINT) -> float:
        """SIGINT, as Ctrl-C sends it; returns the seconds until the process ended."""
        t0 = time.monotonic()
        self.proc.send_signal(sig)
        while self.proc.poll() is None and time.monotonic() - t0 < 30:
            r, _, _ = select.select([self.master], [], [], 0.01)
            if r:
                with contextlib.suppress(OSError):
                    self.out += os.read(self.master, 65536)
        took = time.monotonic() - t0
        self.proc.wait(30)
        with contextlib.suppress(OSError):
            while select.select([self.master], [], [], 0.05)[0]:
                chunk = os.read(self.master, 65536)
                if not chunk:
                    break
                self.out += chunk
        os.close(self.master)
        return took

    def screen(self, cols: int = 80, rows: int = 24) -> list[str]:
        screen = pyte.Screen(cols, rows)
        pyte.ByteStream(screen).feed(self.out)
        return list(screen.display)
