"""Opening a database only to read it (``pymb export``, ``pymb info``, the
readers of :mod:`pymb.store.reader`), without writing anything, on
read-only media too, and without leaving ``-wal``/``-shm`` files behind.

A WAL database needs its ``-shm`` index to be read. Where pymb may write
(the usual case), the database is opened read-write with ``query_only``:
SQLite then makes the index if it is missing and, being the last connection
to close, removes ``-wal`` and ``-shm`` as a writer's last close does; the
file's content never changes. Where it may not (a card mounted read-only,
a directory of another user), a database with no ``-wal`` beside it is
whole in its file and is opened ``immutable`` (no index, no lock, nothing
made); one whose ``-wal`` survives is opened read-only through the files
that are there.
"""

from __future__ import annotations

import os
import sqlite3
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from pymb.errors import InvalidArgument

__all__ = ["open_readonly", "reading"]


def _may_write(path: Path) -> bool:
    try:
        st = os.statvfs(path.parent)
    except OSError:
        return False
    if st.f_flag & os.ST_RDONLY:
        return False
    return os.access(path, os.W_OK) and os.access(path.parent, os.W_OK | os.X_OK)


def open_readonly(path: str | os.PathLike[str]) -> sqlite3.Connection:
    """A connection that only reads the database at ``path`` (see the module
    docstring); InvalidArgument if there is no such file."""
    p = Path(path)
    if not p.is_file():
        raise InvalidArgument(f"no such database: {path}")
    # A URI, escaped: '%', '#' and '?' in a file name are the file name's.
    uri = p.resolve().as_uri()
    if _may_write(p):
        con = sqlite3.connect(f"{uri}?mode=rw", uri=True, isolation_level=None)
        con.execute("PRAGMA query_only = 1")
        return con
    wal = Path(f"{p}-wal")
    if wal.exists() and wal.stat().st_size > 0:
        return sqlite3.connect(f"{uri}?mode=ro", uri=True, isolation_level=None)
    return sqlite3.connect(f"{uri}?mode=ro&immutable=1", uri=True, isolation_level=None)


@contextmanager
def reading(path: str | os.PathLike[str]) -> Iterator[sqlite3.Connection]:
    """:func:`open_readonly` for one read, closed after it: an ``sqlite3``
    error opening or reading is the InvalidArgument "PATH is not a readable
    pymb database: what SQLite said"."""
    try:
        con = open_readonly(path)
        try:
            yield con
        finally:
            con.close()
    except sqlite3.Error as e:
        raise InvalidArgument(f"{path} is not a readable pymb database: {e}") from None
