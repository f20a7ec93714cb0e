"""One writer per database: an exclusive ``flock`` on the database file,
held as long as a :class:`~pymb.store.SqliteSink` has it open.

SQLite locks byte ranges with ``fcntl``; ``flock`` locks are apart from
those on Linux, so readers (``pymb export``, ``sqlite3``, the forwarder's
connection) never see this lock, and a second writer is refused before it
writes anything, even the schema. The kernel drops the lock when its holder
dies (SIGKILL, power cut): nothing stale is left behind. The refusal names
the holder, found in ``/proc/locks``.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
from pathlib import Path

from pymb.errors import InvalidArgument

__all__ = ["DatabaseInUse", "WriterLock", "describe_process", "writer_of"]


class DatabaseInUse(InvalidArgument):
    """Another process writes to the database (``pymb log`` exits 2)."""


def describe_process(pid: int) -> str:
    """``pymb log, PID 1234`` (or the program's name) for a running process."""
    try:
        argv = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
    except OSError:
        return f"PID {pid}"
    words = [a.decode("utf-8", "replace") for a in argv if a]
    name = ""
    for i, word in enumerate(words):
        base = os.path.basename(word)
        if base == "pymb" or (base == "-m" and words[i + 1:i + 2] == ["pymb"]):
            rest = words[i + (2 if base == "-m" else 1):]
            command = next((w for w in rest if not w.startswith("-")), "")
            name = f"pymb {command}".strip()
            break
    if not name and words:
        name = os.path.basename(words[0])
    return f"{name}, PID {pid}" if name else f"PID {pid}"


def _holder(fd: int) -> int | None:
    """The PID holding a flock on the file open at ``fd`` (from /proc/locks)."""
    st = os.fstat(fd)
    want = f"{os.major(st.st_dev):02x}:{os.minor(st.st_dev):02x}:{st.st_ino}"
    try:
        lines = Path("/proc/locks").read_text().splitlines()
    except OSError:
        return None
    for line in lines:
        parts = line.split()
        if len(parts) >= 6 and parts[1] == "FLOCK" and parts[5] == want:
            with contextlib.suppress(ValueError):
                pid = int(parts[4])
                if pid > 0:
                    return pid
    return None


def writer_of(path: str | os.PathLike[str]) -> str | None:
    """The process that holds the writer's lock on ``path`` now (``pymb log,
    PID 1234``), or None: read from ``/proc/locks``, taking no lock."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC)
    except OSError:
        return None
    try:
        pid = _holder(fd)
    finally:
        os.close(fd)
    return None if pid is None else describe_process(pid)


class WriterLock:
    """The exclusive right to write ``path`` (an existing file), taken at once
    or refused with :class:`DatabaseInUse` naming the process that has it."""

    def __init__(self, path: Path) -> None:
        self.fd: int | None = os.open(path, os.O_RDONLY | os.O_CLOEXEC)
        try:
            fcntl.flock(self.fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            pid = _holder(self.fd)
            self.release()
            who = "another process" if pid is None else describe_process(pid)
            raise DatabaseInUse(f"{path} is being written by {who}; stop it first or log "
                                "to another file") from None
        except BaseException:
            self.release()
            raise

    def release(self) -> None:
        """Let the next writer in."""
        if self.fd is not None:
            fd, self.fd = self.fd, None
            os.close(fd)
