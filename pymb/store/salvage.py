"""Salvage: every row that can still be read from a damaged pymb database,
copied into a new one (``pymb salvage``; ``pymb export`` and ``pymb info``
read a damaged file through it).

The damaged file is never opened for writing: it is copied (with its
``-wal``) into a temporary folder and read there. A header SQLite no longer
takes (overwritten, zeroed) is rewritten in the copy from what pymb's files
always have (the page size found by trying, UTF-8, the schema format).
Each table is then read in id order, a thousand rows at a time; where a read
fails (a zeroed or cut page), the next readable id is looked for further on
(doubling the step, then narrowed down by bisection), so one bad page loses
the rows it held and no others. SQLite's own recovery (``.recover``) needs
the ``sqlite_dbpage`` table, which Debian's SQLite does not build.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import sqlite3
import struct
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

from pymb.errors import InvalidArgument, OutputError
from pymb.store.damage import SQLITE_HEADER, looks_like_pymb
from pymb.store.files import create
from pymb.store.pages import Column, fits, leaf_rows

__all__ = ["Salvaged", "salvage"]

_BATCH = 1000
_PAGE_SIZES = (8192, 4096, 16384, 1024, 2048, 32768, 65536)
_MAX_ID = 1 << 62


@dataclass
class Salvaged:
    """What a salvage read: rows copied per table, and the ids (or rows) it
    could not read."""

    copied: dict[str, int] = field(default_factory=dict)
    #: table -> [first, last] id ranges that could not be read
    lost: dict[str, list[tuple[int, int]]] = field(default_factory=dict)
    #: tables that could not be read at all, or only in part (no ids to say which rows)
    partial: list[str] = field(default_factory=list)
    header_rewritten: bool = False
    #: table -> rows read from pages its b-tree no longer leads to
    from_pages: dict[str, int] = field(default_factory=dict)

    def lines(self) -> list[str]:
        """What was copied and what was skipped, a line each."""
        out = []
        if self.header_rewritten:
            out.append("the file's header was damaged: read with a header rebuilt in a copy")
        for table in ("samples", "events", "hub_changes", "devices"):
            if table in self.copied:
                out.append(f"{table}: {self.copied[table]:,} row(s) read")
        for table, n in self.from_pages.items():
            out.append(f"{table}: {n:,} of them read from pages its index no longer "
                       "leads to")
        for table, ranges in self.lost.items():
            where = ", ".join(_span(lo, hi) for lo, hi in ranges[:5])
            more = f" and {len(ranges) - 5} more ranges" if len(ranges) > 5 else ""
            bounded = [hi - lo + 1 for lo, hi in ranges if hi < _MAX_ID]
            most = f" (at most {sum(bounded):,} rows)" if len(bounded) == len(ranges) else ""
            out.append(f"{table}: skipped unreadable ids {where}{more}{most}")
        out += [f"{t}: read in part, the rest unreadable" for t in self.partial]
        return out

    @property
    def skipped(self) -> bool:
        """True if some rows could not be read."""
        return bool(self.lost or self.partial)


def _span(lo: int, hi: int) -> str:
    if hi >= _MAX_ID:
        return f"{lo} and above"
    return str(lo) if lo == hi else f"{lo}..{hi}"


def _header(page_size: int, pages: int, wal: bool) -> bytes:
    """A database header as SQLite writes one (no freelist)."""
    size = 1 if page_size == 65536 else page_size
    v = 2 if wal else 1
    h = bytearray(100)
    h[0:16] = SQLITE_HEADER
    struct.pack_into(">HBBBBBB", h, 16, size, v, v, 0, 64, 32, 32)
    struct.pack_into(">IIIIIIIIIIII", h, 24, 1, pages, 0, 0, 1, 4, 0, 0, 1, 0, 0, 0)
    struct.pack_into(">II", h, 92, 1, 3040001)
    return bytes(h)


def _open_copy(path: Path, lenient: bool = True) -> sqlite3.Connection:
    """The copy, read only (it may make its -shm: it is a copy); ``lenient``:
    a schema entry whose table is damaged does not stop the others being read."""
    con = sqlite3.connect(path, isolation_level=None)
    con.execute("PRAGMA query_only = 1")
    if lenient:
        con.execute("PRAGMA writable_schema = ON")
    return con


def _readable(path: Path, lenient: bool) -> bool:
    """True if the copy's list of tables reads (and names pymb's samples)."""
    try:
        con = _open_copy(path, lenient)
        try:
            names = {n for (n,) in con.execute("SELECT name FROM sqlite_master")}
            return "samples" in names
        finally:
            con.close()
    except sqlite3.Error:
        return False


def _tables(path: Path) -> set[str] | None:
    """The tables SQLite lists in the copy as it is (None: it lists none, the
    file is damaged or no SQLite file)."""
    try:
        con = _open_copy(path, False)
        try:
            return {str(n) for (n,) in con.execute(
                "SELECT name FROM sqlite_master WHERE type = 'table'")}
        finally:
            con.close()
    except sqlite3.Error:
        return None


def _repair_header(copy: Path) -> bool:
    """Rewrite a header SQLite does not take (True if it was rewritten)."""
    with open(copy, "rb") as f:
        magic = f.read(16) == SQLITE_HEADER
    if _readable(copy, False) or (magic and _readable(copy, True)):
        return False
    size = copy.stat().st_size
    wal = Path(f"{copy}-wal").exists()
    with open(copy, "r+b") as f:
        old = f.read(100)
        for lenient in (False, True):
            for ps in _PAGE_SIZES:
                f.seek(0)
                f.write(_header(ps, max(1, size // ps), wal))
                f.flush()
                if _readable(copy, lenient):
                    return True
        f.seek(0)
        f.write(old)
    return False


def _copy(src: Path, into: Path) -> Path:
    """The damaged file (and its -wal) copied into ``into``; the copy's path."""
    dst = into / "damaged.sqlite"
    shutil.copyfile(src, dst)
    wal = Path(f"{src}-wal")
    if wal.exists():
        shutil.copyfile(wal, f"{dst}-wal")
    _pad(dst)
    return dst


def _pad(copy: Path) -> None:
    """A cut file padded with zeros to the pages its header counts: the pages
    that pointed past its end read as damaged pages, the others as they are."""
    with open(copy, "r+b") as f:
        head = f.read(100)
        if len(head) < 100 or not head.startswith(SQLITE_HEADER):
            return
        size = struct.unpack_from(">H", head, 16)[0]
        page = 65536 if size == 1 else size
        pages = struct.unpack_from(">I", head, 28)[0]
        end = f.seek(0, os.SEEK_END)
        want = page * pages
        if page in _PAGE_SIZES and end < want <= 1 << 40:
            f.truncate(want)


def _next_readable(con: sqlite3.Connection, table: str, after: int) -> int | None:
    """The lowest id above ``after`` that can be read (None: none can)."""
    def first_from(i: int) -> int | bool | None:  # an id, None (no more), False (unreadable)
        try:
            row = con.execute(f"SELECT * FROM {table} WHERE rowid >= ? ORDER BY rowid LIMIT 1",
                              (i,)).fetchone()
        except sqlite3.DatabaseError:
            return False
        return None if row is None else int(row[0])

    step = 1
    good: int | bool | None = False
    lo = after + 1
    while lo + step < _MAX_ID:
        good = first_from(lo + step)
        if good is not False:
            break
        step *= 2
    if good is False or good is None:
        return None
    # the first readable id lies in (after, good]: narrow it down
    bad, hi = after, int(good)
    top = lo + step
    while top - bad > 1:
        mid = (bad + top) // 2
        got = first_from(mid)
        if got is False:
            bad = mid
        else:
            top = mid
            if got is not None:
                hi = min(hi, int(got))
    return hi


def _copy_rows(src: sqlite3.Connection, dst: sqlite3.Connection, table: str,
               columns: list[str], result: Salvaged) -> None:
    """Copy ``table`` (id order, around unreadable pages)."""
    cols = ", ".join(columns)
    marks = ", ".join("?" * len(columns))
    insert = f"INSERT OR IGNORE INTO {table}({cols}) VALUES ({marks})"
    after, n = 0, 0
    while True:
        try:
            # ">= after + 1", not "> after": a seek past a key steps over the
            # page it is on, which may be the bad one
            rows = src.execute(f"SELECT rowid, {cols} FROM {table} WHERE rowid >= ? "
                               f"ORDER BY rowid LIMIT {_BATCH}", (after + 1,)).fetchall()
        except sqlite3.DatabaseError:
            rows = None
        if rows is None:
            # read one at a time up to the bad page, then look past it
            while True:
                try:
                    row = src.execute(f"SELECT rowid, {cols} FROM {table} WHERE rowid >= ? "
                                      "ORDER BY rowid LIMIT 1", (after + 1,)).fetchone()
                except sqlite3.DatabaseError:
                    break
                if row is None:
                    break
                dst.execute(insert, row[1:])
                after, n = int(row[0]), n + 1
            nxt = _next_readable(src, table, after)
            last = nxt - 1 if nxt is not None else _MAX_ID
            result.lost.setdefault(table, []).append((after + 1, last))
            if nxt is None:
                break
            after = nxt - 1
            continue
        if not rows:
            break
        dst.executemany(insert, [r[1:] for r in rows])
        after, n = int(rows[-1][0]), n + len(rows)
    result.copied[table] = n


def _copy_all(src: sqlite3.Connection, dst: sqlite3.Connection, table: str,
              columns: list[str], result: Salvaged) -> None:
    """Copy a table without ids (WITHOUT ROWID, small tables) as far as it reads."""
    cols = ", ".join(columns)
    insert = f"INSERT OR REPLACE INTO {table}({cols}) VALUES ({', '.join('?' * len(columns))})"
    n = 0
    # the new file's own format rows stay (the damaged file's are its old ones)
    where = " WHERE key NOT IN ('schema_version', 'schema_sql', 'pymb_version')" \
        if table == "meta" else ""
    try:
        for row in src.execute(f"SELECT {cols} FROM {table}{where}"):
            dst.execute(insert, row)
            n += 1
    except sqlite3.DatabaseError:
        result.partial.append(table)
    result.copied[table] = n


def _from_pages(copy: Path, src: sqlite3.Connection, dst: sqlite3.Connection,
                result: Salvaged) -> None:
    """The rows of the lost id ranges that are still on a page (a cut file, a
    zeroed interior page), read from the pages themselves."""
    shapes: dict[str, list[Column]] = {}
    names: dict[str, list[str]] = {}
    for table in result.lost:
        info = src.execute(f"PRAGMA table_info({table})").fetchall()
        shapes[table] = [(str(r[2]), bool(r[3]), bool(r[5])) for r in info]
        names[table] = [str(r[1]) for r in info]
    found: dict[str, set[int]] = {t: set() for t in result.lost}
    for rowid, values in leaf_rows(copy):
        for table, ranges in result.lost.items():
            if not any(lo <= rowid <= hi for lo, hi in ranges) or \
                    not fits(values, shapes[table]):
                continue
            pk = [i for i, c in enumerate(shapes[table]) if c[2]]
            if pk:
                values[pk[0]] = rowid
            cols = ", ".join(names[table])
            cur = dst.execute(f"INSERT OR IGNORE INTO {table}({cols}) VALUES "
                              f"({', '.join('?' * len(values))})", values)
            if cur.rowcount:
                found[table].add(rowid)
            break
    for table, ids in found.items():
        if not ids:
            continue
        result.from_pages[table] = len(ids)
        result.copied[table] = result.copied.get(table, 0) + len(ids)
        result.lost[table] = _gaps(result.lost[table], ids)
    result.lost = {t: r for t, r in result.lost.items() if r}


def _gaps(ranges: list[tuple[int, int]], ids: set[int]) -> list[tuple[int, int]]:
    """The parts of ``ranges`` that ``ids`` do not cover (an open range stays
    open above the highest id found in it)."""
    out: list[tuple[int, int]] = []
    for lo, hi in ranges:
        inside = sorted(i for i in ids if lo <= i <= hi)
        start = lo
        for i in inside:
            if i > start:
                out.append((start, i - 1))
            start = i + 1
        if start <= hi:
            out.append((start, hi))
    return out


def _columns(con: sqlite3.Connection, table: str) -> list[str]:
    return [str(r[1]) for r in con.execute(f"PRAGMA table_info({table})")]


def salvage(damaged: str | os.PathLike[str], new: str | os.PathLike[str]) -> Salvaged:
    """Copy every readable row of the pymb database ``damaged`` into the new
    database ``new`` (which must not exist); ``damaged`` is only read."""
    src_path, new_path = Path(damaged), Path(new)
    if os.fspath(new) == "-":  # stdout for export --csv; no file named '-' here
        raise InvalidArgument("NEW '-': salvage writes a new database file, not stdout; "
                              "give its name")
    if not src_path.is_file():
        raise InvalidArgument(f"no such database: {damaged}")
    if new_path.exists() or os.path.lexists(new_path):
        raise InvalidArgument(f"{new} exists: salvage writes a new file; choose another name")
    if os.fspath(new).endswith(("/", os.sep)):  # Path() would drop the slash: a file
        raise InvalidArgument(f"{new} names a folder; give the new database's file name")
    if not new_path.parent.is_dir():
        raise InvalidArgument(f"the directory of {new} does not exist")
    with tempfile.TemporaryDirectory(prefix="pymb-salvage-") as tmp:
        try:
            copy = _copy(src_path, Path(tmp))
        except OSError as e:
            raise InvalidArgument(f"cannot read {damaged}: {e.strerror}") from None
        listed = _tables(copy)
        if listed is not None and "samples" not in listed and not looks_like_pymb(copy):
            if "pymb_values" in listed:
                raise InvalidArgument(f"{damaged} is what pymb collect writes, not pymb log: "
                                      "salvage copies pymb log's databases")
            raise InvalidArgument(f"{damaged} is not a pymb database")
        result = Salvaged(header_rewritten=_repair_header(copy))
        if not _readable(copy, True):
            raise InvalidArgument(f"{damaged}: not even the list of tables can be read; "
                                  "nothing to salvage")
        src = _open_copy(copy)
        try:
            tables = {str(n) for (n,) in src.execute(
                "SELECT name FROM sqlite_master WHERE type = 'table'")}
            if not {"meta", "samples"} <= tables and not looks_like_pymb(copy):
                raise InvalidArgument(f"{damaged} is not a pymb database")
            made = new_path.with_name(f".{new_path.name}.salvage")
            try:  # NEW's folder takes a file (not read-only, not another user's)
                with contextlib.suppress(FileNotFoundError):
                    made.unlink()
                os.close(os.open(made, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))
                made.unlink()
            except OSError as e:
                raise InvalidArgument(f"cannot write {new}: {e.strerror}") from None
            try:  # the file in the making goes, whatever stops it (Ctrl-C too)
                create(made)
                dst = sqlite3.connect(made, isolation_level=None)
                try:
                    dst.execute("BEGIN")
                    for table in _ORDER:
                        if table not in tables:
                            continue
                        try:
                            if not _columns(dst, table):  # not in every pymb file (outbox)
                                sql = src.execute("SELECT sql FROM sqlite_master WHERE name = ?",
                                                  (table,)).fetchone()[0]
                                dst.execute(sql)
                            cols = [c for c in _columns(src, table) if c in _columns(dst, table)]
                        except sqlite3.DatabaseError:
                            result.partial.append(table)
                            continue
                        if table in _WITH_IDS:
                            _copy_rows(src, dst, table, cols, result)
                        else:
                            _copy_all(src, dst, table, cols, result)
                    if result.lost:
                        _from_pages(copy, src, dst, result)
                    dst.execute("COMMIT")
                finally:
                    dst.close()
                try:
                    os.link(made, new_path)  # never over a file that appeared meanwhile
                except FileExistsError:
                    raise InvalidArgument(f"{new} appeared meanwhile: salvage writes a new "
                                          "file; choose another name") from None
            except sqlite3.OperationalError as e:
                if str(e) in _WRITE_FAILED:
                    raise OutputError(f"cannot write {new}: {e}; nothing was written") from None
                # (another failure, an I/O error of either file: the copy stops whole)
                raise OutputError(f"salvage into {new} stopped: {e}; nothing was "
                                  "written") from None
            except OSError as e:
                raise OutputError(f"cannot write {new}: {e.strerror}; nothing was "
                                  "written") from None
            finally:
                for side in ("", "-journal", "-wal", "-shm"):
                    with contextlib.suppress(OSError):
                        Path(f"{made}{side}").unlink(missing_ok=True)
        finally:
            src.close()
    return result


#: the order rows are copied in (those referred to first)
#: SQLite's words for a write that failed (the new file's disk, not the damaged file)
_WRITE_FAILED = frozenset({"database or disk is full", "unable to open database file",
                           "attempt to write a readonly database"})
_ORDER = ("meta", "states", "maps", "devices", "channels", "samples", "hub_changes", "events",
          "outbox")
_WITH_IDS = {"devices", "samples", "events"}
