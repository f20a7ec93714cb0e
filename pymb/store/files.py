"""A new file appears whole: made beside its path, then linked or renamed in."""

from __future__ import annotations

import contextlib
import os
import sqlite3
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

from pymb.errors import InvalidArgument
from pymb.store.schema import install, new_file

__all__ = ["create", "remove_stale_creations", "write_beside"]

T = TypeVar("T")


def _creating(path: Path, pid: int) -> Path:
    """Where process ``pid`` makes the database ``path`` before linking it in."""
    return path.with_name(f".{path.name}.{pid}.creating")


def remove_stale_creations(path: Path) -> None:
    """Delete what a process killed (SIGKILL, power loss) while making
    ``path`` left beside it: ``.NAME.PID.creating`` files whose PID is no
    longer running. A file of a running process is its own business."""
    prefix, suffix = f".{path.name}.", ".creating"
    try:
        names = [p.name for p in path.parent.iterdir()
                 if p.name.startswith(prefix) and p.name.endswith(suffix)]
    except OSError:
        return
    for name in names:
        pid = name[len(prefix):-len(suffix)]
        if not pid.isdigit() or int(pid) == os.getpid():
            continue
        try:
            os.kill(int(pid), 0)
            continue  # running
        except ProcessLookupError:
            pass
        except (PermissionError, OverflowError):
            continue  # another user's process, or no PID at all: not ours to judge
        with contextlib.suppress(OSError):
            (path.parent / name).unlink()


def create(path: Path) -> None:
    """A new database appears whole: made beside ``path`` with its schema,
    then linked into place (a process killed meanwhile leaves no half-made
    file at ``path``; what it leaves beside it, the next open removes)."""
    tmp = _creating(path, os.getpid())
    try:
        con = sqlite3.connect(tmp, isolation_level=None)
        try:
            new_file(con)
            install(con)
        finally:
            con.close()
        try:
            os.link(tmp, path)  # fails if another process made it meanwhile: use theirs
        except FileExistsError:
            pass
        except OSError:  # no hard links here (a FAT SD card)
            if not path.exists():
                os.replace(tmp, path)
    finally:
        with contextlib.suppress(OSError):
            tmp.unlink()


def write_beside(out: str, prefix: str, suffix: str, write: Callable[[int, str], T], *,
                 keep_mode: bool) -> T:
    """Write a temporary file beside ``out`` and rename it over ``out`` when done.

    ``write(fd, tmp)`` fills the temporary file (it owns ``fd``). The file gets the mode of the
    ``out`` it replaces with ``keep_mode``, else the umask's. On any failure the temporary file
    goes and ``out`` stays as it was; an ``OSError`` becomes a one-line ``InvalidArgument``.
    """
    folder = os.path.dirname(os.path.abspath(out))
    try:
        fd, tmp = tempfile.mkstemp(prefix=prefix, suffix=suffix, dir=folder)
    except OSError as e:
        raise InvalidArgument(f"cannot write {out}: {e.strerror}") from None
    try:
        result = write(fd, tmp)
        if keep_mode and os.path.exists(out):
            with contextlib.suppress(OSError):
                os.chmod(tmp, os.stat(out).st_mode & 0o7777)
        else:
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, out)
    except OSError as e:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise InvalidArgument(f"cannot write {out}: {e.strerror}") from None
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    return result
