"""Helpers of the service tests: a listening notify socket (the service
manager's end of sd_notify, no systemd needed) and ``pymb log`` children of
a simulated CoolPro, started in their own session (no controlling terminal,
as under systemd)."""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import PYMB, PYMB_ENV, wait_until

from pymb.sim import SimulatorProcess


def set_clock(file: Path, spec: str) -> None:
    """What libfaketime reads at the next call: ``@1970-01-02 00:00:00``, ``+0``, ``-3600``."""
    tmp = file.with_suffix(".new")
    tmp.write_text(spec + "\n")
    os.replace(tmp, file)  # never seen half-written


def faketime_env(file: Path, spec: str) -> dict[str, str]:
    """The environment of a child whose wall clock ``file`` sets."""
    if shutil.which("faketime") is None:
        pytest.fail("faketime is not installed: .ci/setup installs it")
    # the library the faketime command preloads (its path has the loader's $LIB):
    # the multi-threaded one (-m): the plain one parses the file into static
    # buffers, so a thread reading the clock while another re-reads the file
    # can get the real time (libfaketime issue 151; pymb log runs threads)
    lib = subprocess.run(["faketime", "-m", "-f", "+0", "sh", "-c", 'printf %s "$LD_PRELOAD"'],
                         capture_output=True, text=True, check=True, timeout=30).stdout
    assert "libfaketimeMT" in lib
    set_clock(file, spec)
    # FORCE_MONOTONIC_FIX=0: else its pthread_cond_timedwait times out at once
    # on a monotonic condition variable with the monotonic clock left real, and
    # every wait for Python's GIL spins (5x the CPU of a 2-thread process here:
    # under load, a poll slot of 50 ms sees no reply)
    return {**PYMB_ENV, "LD_PRELOAD": lib, "FAKETIME_TIMESTAMP_FILE": str(file),
            "FAKETIME_NO_CACHE": "1", "FAKETIME_DONT_FAKE_MONOTONIC": "1",
            "FAKETIME_FORCE_MONOTONIC_FIX": "0"}


class NotifyListener:
    """A datagram socket bound where ``$NOTIFY_SOCKET`` says (``@name``: the
    abstract namespace); collects what arrives as lists of assignments."""

    def __init__(self, where: str) -> None:
        self.where = where
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(b"\0" + where[1:].encode() if where.startswith("@") else where)
        self.sock.settimeout(0.05)
        self.messages: list[list[str]] = []

    def poll(self) -> list[list[str]]:
        """Take what has arrived; returns everything received so far."""
        while True:
            try:
                data = self.sock.recv(4096)
            except TimeoutError:
                return self.messages
            self.messages.append(data.decode().split("\n"))

    def lines(self) -> list[str]:
        """Every assignment received so far, in order."""
        return [a for m in self.poll() for a in m]

    def close(self) -> None:
        """Close (and remove a path socket)."""
        self.sock.close()
        if not self.where.startswith("@"):
            Path(self.where).unlink(missing_ok=True)


@pytest.fixture
def coolpro() -> Iterator[SimulatorProcess]:
    """A simulated CoolPro (address 40) on Modbus TCP in its own process."""
    sim = SimulatorProcess(["coolpro", "--tcp", "127.0.0.1:0"], quiet=True).start()
    try:
        yield sim
    finally:
        sim.stop()


def start_log(*args: str, env: dict[str, str] | None = None,
              cwd: Path | None = None) -> subprocess.Popen[str]:
    """``pymb log ARGS`` in a new session (no controlling terminal); stderr a pipe."""
    return subprocess.Popen([*PYMB, "log", *args], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True, start_new_session=True,
                            env={**PYMB_ENV, **(env or {})}, cwd=cwd)


class StderrLines:
    """The child's stderr lines as they come (a reader thread collects them)."""

    def __init__(self, proc: subprocess.Popen[str]) -> None:
        self.lines: list[str] = []
        self.proc = proc
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()

    def _read(self) -> None:
        assert self.proc.stderr is not None
        for line in iter(self.proc.stderr.readline, ""):
            self.lines.append(line.rstrip("\n"))

    def wait_for(self, text: str, timeout: float = 30, after: int = 0) -> int:
        """Wait for a line (from index ``after`` on) containing ``text``; its index."""
        def seen() -> int | None:
            return next((i for i, line in enumerate(self.lines) if i >= after and text in line),
                        None)
        got = wait_until(lambda: seen() is not None, f"a line with {text!r} on stderr "
                         f"(got {self.lines[-5:]})", timeout)
        assert got
        i = seen()
        assert i is not None
        return i

    def text(self) -> str:
        """Everything so far (all of it once the child ended and was waited for)."""
        if self.proc.poll() is not None:
            self.thread.join(10)
        return "\n".join(self.lines)


def count_rows(db: Path, sql: str = "SELECT COUNT(*) FROM samples") -> int:
    """One number from a database (0 while it does not exist yet)."""
    import sqlite3
    if not db.exists():
        return 0
    try:
        con = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=5)
        try:
            return int(con.execute(sql).fetchone()[0] or 0)
        finally:
            con.close()
    except sqlite3.Error:
        return 0


def wait_rows(db: Path, n: int, proc: subprocess.Popen[str], timeout: float = 30,
              sql: str = "SELECT COUNT(*) FROM samples") -> int:
    """Wait until ``sql`` counts at least ``n`` (the child alive meanwhile)."""
    return wait_until(lambda: (c := count_rows(db, sql)) >= n and c, f"{n} rows of {sql}",
                      timeout, alive=lambda: proc.poll() is None)


__all__ = [
    "NotifyListener",
    "StderrLines",
    "coolpro",
    "count_rows",
    "start_log",
    "wait_rows",
]
