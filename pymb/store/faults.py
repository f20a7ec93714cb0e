"""Storage faults said plainly: a failure of the database's disk (full,
read-only, no permission, the file or its directory gone, an I/O error) as
one line with the operating system's reason and what to do, never SQLite's
internal words ("cannot rollback - no transaction is active").

SQLite reports most of these as its own codes (``SQLITE_FULL``,
``SQLITE_READONLY``, ``SQLITE_CANTOPEN``, ``SQLITE_IOERR``); the reason is
found by looking at the file system itself.
"""

from __future__ import annotations

import errno
import os
import sqlite3
import stat
from pathlib import Path

from pymb.errors import OutputError

__all__ = ["file_open_error", "is_storage_fault", "storage_error", "vanished"]

#: SQLite's primary result codes that mean the storage failed (not the file's content)
_STORAGE_CODES = {"SQLITE_FULL", "SQLITE_READONLY", "SQLITE_CANTOPEN", "SQLITE_IOERR",
                  "SQLITE_PERM", "SQLITE_NOLFS"}

_TODO = {
    errno.ENOSPC: "free some space on it, or bound the database with --max-mb",
    errno.EDQUOT: "raise the quota, or bound the database with --max-mb",
    errno.EROFS: "the file system is read-only (an emergency remount after disk errors "
                 "looks like this): check the disk, then mount it read-write",
    errno.EACCES: "let the user running pymb write the file and its directory",
    errno.EPERM: "let the user running pymb write the file and its directory",
    errno.ENOENT: "restore the directory (or log to another --out)",
    errno.EIO: "the disk failed to read or write: check it (dmesg)",
}


def _code(e: BaseException) -> str:
    """SQLite's primary code of ``e`` (``SQLITE_IOERR`` for ``SQLITE_IOERR_WRITE``)."""
    return "_".join(str(getattr(e, "sqlite_errorname", "") or "").split("_")[:2])


def is_storage_fault(e: BaseException) -> bool:
    """True for an OS error, or a SQLite error that says the storage failed."""
    if isinstance(e, OSError):
        return True
    return isinstance(e, sqlite3.Error) and _code(e) in _STORAGE_CODES


def _missing(path: Path, *, directory: bool = False) -> bool:
    """True if ``path`` is not there (or, with ``directory``, is no directory);
    False when it cannot be told (no permission to look): not missing."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return True
    except OSError as e:
        return e.errno == errno.ENOTDIR
    return directory and not stat.S_ISDIR(st.st_mode)


def vanished(path: Path, *, made: bool = True) -> str | None:
    """Why the database at ``path`` is no longer there (None: it is, or no
    permission to look). ``made=False``: a database about to be made, only
    its directory must be there."""
    if _missing(path.parent, directory=True):
        return f"its directory {path.parent} was removed"
    if made and _missing(path):
        return "the file was deleted or moved away"
    return None


def _probe(path: Path, e: BaseException, opening: bool) -> tuple[int | None, str]:
    """(errno, words) of what went wrong with the storage of ``path``."""
    gone = vanished(path, made=not opening)
    if gone is not None:
        return errno.ENOENT, gone
    if isinstance(e, OSError) and e.errno:
        return e.errno, e.strerror or os.strerror(e.errno)
    code = _code(e)
    where = path.parent
    try:
        st = os.statvfs(where)
    except OSError:
        st = None
    if st is not None and st.f_flag & os.ST_RDONLY:
        return errno.EROFS, os.strerror(errno.EROFS)
    if code == "SQLITE_FULL" or (st is not None and st.f_bavail * st.f_frsize < 65536):
        return errno.ENOSPC, os.strerror(errno.ENOSPC)
    if not os.access(where, os.W_OK | os.X_OK) or (not _missing(path) and
                                                   not os.access(path, os.W_OK)):
        return errno.EACCES, os.strerror(errno.EACCES)
    if code == "SQLITE_IOERR":
        return errno.EIO, os.strerror(errno.EIO)
    return None, f"{e} ({code or type(e).__name__})"


def storage_error(path: Path, e: BaseException, *, opening: bool = False) -> OutputError:
    """The one-line :class:`OutputError` (``pymb log`` exits 5) for a storage
    failure of the database at ``path`` while opening it or writing to it."""
    num, words = _probe(path, e, opening)
    reason = words if num is None or num == errno.ENOENT else \
        f"{words} ({errno.errorcode.get(num, num)})"
    todo = _TODO.get(num) if num is not None else None
    if opening and num == errno.ENOENT:
        reason = f"its directory {path.parent} does not exist"
        todo = "create it, or mount the disk that holds it (or log to another --out)"
    head = f"cannot open the database {path}" if opening else f"cannot write to {path}"
    tail = "" if opening else ("; everything committed before is intact, the batch being "
                               "written was lost")
    return OutputError(f"{head}: {reason}" + (f"; {todo}" if todo else "") + tail)


def file_open_error(path: str, e: OSError) -> OutputError:
    """The one-line :class:`OutputError` (exit 5, as for a database) for a
    text output (CSV, JSON Lines, line protocol) that cannot be opened for
    writing: the operating system's reason and what to do."""
    num = e.errno
    words = e.strerror or str(e)
    if num == errno.ENOENT:
        words = f"its directory {Path(path).parent} does not exist"
        todo: str | None = "create it, or mount the disk that holds it (or write to another --out)"
    else:
        todo = _TODO.get(num) if num is not None else None
        if num is not None:
            words += f" ({errno.errorcode.get(num, num)})"
    return OutputError(f"cannot open {path}: {words}" + (f"; {todo}" if todo else ""))
