"""Rows read straight from a database file's pages, for what its b-trees no
longer lead to (a cut file whose upper pages are gone, a zeroed interior
page): every table leaf page of the file (and of its WAL, newest frames
first) that is not on the free list, its cells decoded as SQLite's record
format says (https://www.sqlite.org/fileformat2.html). A row is taken for a
table only when its values fit that table's columns (count, types, NOT
NULL). Cells that spill onto overflow pages are not read.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

__all__ = ["Column", "fits", "leaf_rows"]

#: (declared type, NOT NULL, primary key) of a column
Column = tuple[str, bool, bool]
_LEAF = 0x0D
_WAL_HEAD, _FRAME_HEAD = 32, 24
_MAX_FREE = 1 << 24  #: free-list pages looked at, at most


def _varint(b: bytes, i: int) -> tuple[int, int]:
    """SQLite's varint at ``b[i]``: (value, the index after it)."""
    v = 0
    for k in range(8):
        c = b[i + k]
        v = (v << 7) | (c & 0x7F)
        if c < 0x80:
            return v, i + k + 1
    return (v << 8) | b[i + 8], i + 9


def _record(p: bytes) -> list[object] | None:
    """The values of one record (None if it does not parse)."""
    try:
        size, i = _varint(p, 0)
        types = []
        while i < size:
            t, i = _varint(p, i)
            types.append(t)
        j = size
        out: list[object] = []
        for t in types:
            if t == 0:
                out.append(None)
            elif 1 <= t <= 6:
                n = (1, 2, 3, 4, 6, 8)[t - 1]
                out.append(int.from_bytes(p[j:j + n], "big", signed=True))
                j += n
            elif t == 7:
                out.append(struct.unpack_from(">d", p, j)[0])
                j += 8
            elif t in (8, 9):
                out.append(t - 8)
            elif t >= 12:
                n = (t - 12) // 2
                raw = p[j:j + n]
                out.append(bytes(raw) if t % 2 == 0 else raw.decode("utf-8"))
                j += n
            else:
                return None
            if j > len(p):
                return None
        return out
    except (IndexError, struct.error, UnicodeDecodeError):
        return None


def _cells(page: bytes, head: int, usable: int) -> Iterator[tuple[int, list[object]]]:
    """(rowid, values) of each cell of a table leaf page that fits on it."""
    if page[head] != _LEAF:
        return
    count = int.from_bytes(page[head + 3:head + 5], "big")
    local_max = usable - 35
    for k in range(min(count, len(page) // 2)):
        at = head + 8 + 2 * k
        ptr = int.from_bytes(page[at:at + 2], "big")
        if not 0 < ptr < len(page):
            continue
        try:
            size, i = _varint(page, ptr)
            rowid, i = _varint(page, i)
        except IndexError:
            continue
        if size > local_max or i + size > len(page):
            continue  # on overflow pages: not read
        values = _record(page[i:i + size])
        if values is not None:
            yield rowid, values


def _free_pages(f: BinaryIO, page_size: int, first: int) -> set[int]:
    """The pages of the free list (as far as it can be read)."""
    free: set[int] = set()
    trunk = first
    while trunk and trunk not in free and len(free) < _MAX_FREE:
        free.add(trunk)
        f.seek((trunk - 1) * page_size)
        b = f.read(page_size)
        if len(b) < 8:
            break
        nxt, n = struct.unpack_from(">II", b, 0)
        n = min(n, (len(b) - 8) // 4)
        free.update(struct.unpack_from(f">{n}I", b, 8))
        trunk = nxt
    return free


def _pages(path: Path) -> Iterator[tuple[int, bytes, int]]:
    """(page number, bytes, usable size) of the WAL's frames, newest first,
    then of the file's pages not on its free list."""
    with open(path, "rb") as f:
        h = f.read(100)
        if len(h) < 100:
            return
        size = struct.unpack_from(">H", h, 16)[0]
        ps = 65536 if size == 1 else size
        usable = ps - h[20]
        free = _free_pages(f, ps, struct.unpack_from(">I", h, 32)[0])
        wal = Path(f"{path}-wal")
        if wal.exists():
            with open(wal, "rb") as w:
                data = w.read()
            frames = []
            for at in range(_WAL_HEAD, len(data) - _FRAME_HEAD - ps + 1, _FRAME_HEAD + ps):
                no = struct.unpack_from(">I", data, at)[0]
                frames.append((no, data[at + _FRAME_HEAD:at + _FRAME_HEAD + ps]))
            for no, page in reversed(frames):
                yield no, page, usable
        f.seek(0)
        no = 0
        while True:
            page = f.read(ps)
            no += 1
            if len(page) < ps:
                return
            if no not in free:
                yield no, page, usable


def fits(values: list[object], columns: list[Column]) -> bool:
    """True if ``values`` can be a row of a table with these columns."""
    if len(values) != len(columns):
        return False
    for v, (kind, notnull, pk) in zip(values, columns, strict=True):
        kind = kind.upper()
        if v is None:
            if notnull and not pk:
                return False
        elif "INT" in kind:
            if not isinstance(v, int):
                return False
        elif kind == "REAL":
            if not isinstance(v, (int, float)):
                return False
        elif kind == "TEXT":
            if not isinstance(v, str):
                return False
        elif kind == "BLOB" and not isinstance(v, bytes):
            return False
    return True


def leaf_rows(path: Path) -> Iterator[tuple[int, list[object]]]:
    """(rowid, values) of every cell of every table leaf page of the file at
    ``path`` and of its WAL (newest first); which table a row belongs to is
    the caller's to tell (:func:`fits`)."""
    for no, page, usable in _pages(path):
        yield from _cells(page, 100 if no == 1 else 0, usable)
