"""A new database appears whole: made beside its path, then linked in."""

from __future__ import annotations

import contextlib
import os
import sqlite3
from pathlib import Path

from pymb.store.schema import install, new_file

__all__ = ["create", "remove_stale_creations"]


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
