"""A damaged database: found at the start of ``pymb log`` (SQLite's
``quick_check``, bounded in time), never written into, moved aside (kept,
renamed with the time it was found) so that logging goes on in a new file.

A file is taken as a damaged pymb database when SQLite cannot read it as
one (its header overwritten, a page zeroed, the file truncated) but it
holds pymb's schema text; anything else that is not a pymb database is
refused as before (someone's document given as ``--out``).
"""

from __future__ import annotations

import contextlib
import os
import sqlite3
import time
from pathlib import Path

from pymb.errors import OutputError
from pymb.store.files import create
from pymb.store.ids import RESERVED_KEY

__all__ = ["CHECK_SECONDS", "SQLITE_HEADER", "damage", "damaged_error", "id_floor", "is_corruption",
           "looks_like_pymb", "move_aside", "notice", "replace_damaged", "seed_ids",
           "set_aside_if_damaged"]

#: seconds ``quick_check`` may take at the start (a large file on a slow card
#: is checked as far as it gets; damage met later is found when it is written);
#: ``$PYMB_CHECK_SECONDS`` sets another bound (0: no check)
CHECK_SECONDS = 10.0
CHECK_ENV = "PYMB_CHECK_SECONDS"


def check_seconds() -> float:
    """The start's bound: ``$PYMB_CHECK_SECONDS`` if it is a number >= 0, else 10 s."""
    try:
        value = float(os.environ.get(CHECK_ENV, CHECK_SECONDS))
    except ValueError:
        return CHECK_SECONDS
    return value if value >= 0 else CHECK_SECONDS
#: where pymb's schema text is looked for in a file SQLite cannot read
_SCAN_BYTES = 4 << 20
#: text of pymb's schema, as SQLite keeps it in the file (sqlite_schema and meta)
_MARKS = (b"hub_changes", b"unsupported INTEGER NOT NULL DEFAULT 0")
#: SQLite's words for a file whose content is broken (not its storage)
_CORRUPT = ("SQLITE_CORRUPT", "SQLITE_NOTADB")
SQLITE_HEADER = b"SQLite format 3\x00"  #: the first 16 bytes of a SQLite database file


def is_corruption(e: BaseException) -> bool:
    """True for a SQLite error that says the file's content is damaged."""
    name = str(getattr(e, "sqlite_errorname", "") or "")
    if name.startswith(_CORRUPT):
        return True
    text = str(e)
    return isinstance(e, sqlite3.DatabaseError) and (
        "malformed" in text or "file is not a database" in text)


def looks_like_pymb(path: str | os.PathLike[str]) -> bool:
    """True if the file holds pymb's schema text in its first few MB (a pymb
    database whose header or first pages SQLite can no longer read)."""
    try:
        with open(path, "rb") as f:
            head = f.read(_SCAN_BYTES)
    except OSError:
        return False
    return all(m in head for m in _MARKS)


def damage(path: str | os.PathLike[str], seconds: float | None = None) -> str | None:
    """What is wrong with the database at ``path`` (SQLite's first words), or
    None when ``quick_check`` finds nothing within ``seconds`` (default:
    :func:`check_seconds`; a check cut short by the bound is None too).
    Reads only: the connection is
    read-only and writes nothing, not even a ``-shm`` index."""
    seconds = check_seconds() if seconds is None else seconds
    if seconds <= 0:
        return None
    uri = Path(path).resolve().as_uri()
    wal = Path(f"{path}-wal")
    # immutable: nothing is made beside the file (no -wal, no -shm), as long as
    # there is no WAL (a live writer always has one: read through it, consistently)
    how = "mode=ro" if wal.exists() else "mode=ro&immutable=1"
    try:
        con = sqlite3.connect(f"{uri}?{how}", uri=True, isolation_level=None)
    except sqlite3.Error as e:
        return str(e) if is_corruption(e) else None
    deadline = time.monotonic() + seconds
    con.set_progress_handler(lambda: int(time.monotonic() > deadline), 10000)
    try:
        rows = [str(r[0]) for r in con.execute("PRAGMA quick_check(3)")]
    except sqlite3.OperationalError as e:
        if "interrupted" in str(e):
            return None
        return str(e) if is_corruption(e) else None
    except sqlite3.DatabaseError as e:
        return str(e)
    finally:
        con.close()
    if rows == ["ok"]:
        return None
    # one line: SQLite's first row is "*** in database main ***" and a newline
    return "; ".join(" ".join(r.split()) for r in rows)


def id_floor(path: str | os.PathLike[str]) -> int:
    """A sample id above every id the damaged file at ``path`` may hold: the
    highest it can still tell, else one its size (with its WAL) cannot exceed
    (a sample takes more than 8 bytes), so that a new file's ids never repeat
    one a broker or a consumer has seen."""
    size = 0
    for p in (Path(path), Path(f"{path}-wal")):
        with contextlib.suppress(OSError):
            size += p.stat().st_size
    return size // 8


def move_aside(path: Path) -> Path:
    """Rename the damaged database (and its ``-wal`` and ``-shm``, which SQLite
    then reads with it) to ``NAME.damaged-YYYYMMDDTHHMMSSZ``; returns the new
    name. Nothing is deleted."""
    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
    aside = path.with_name(f"{path.name}.damaged-{stamp}")
    n = 1
    while aside.exists():
        n += 1
        aside = path.with_name(f"{path.name}.damaged-{stamp}-{n}")
    for suffix in ("-wal", "-shm"):
        side = Path(f"{path}{suffix}")
        if side.exists():
            os.rename(side, f"{aside}{suffix}")
    os.rename(path, aside)
    return aside


def seed_ids(path: Path, floor: int) -> None:
    """Start the new database's sample ids above ``floor`` (its ``meta`` mark,
    see :mod:`pymb.store.ids`)."""
    con = sqlite3.connect(path, isolation_level=None)
    try:
        con.execute("INSERT OR REPLACE INTO meta VALUES (?, ?)", (RESERVED_KEY, str(floor)))
    finally:
        con.close()


def notice(path: Path, aside: Path, problem: str) -> str:
    """The one line that says a damaged database was moved aside."""
    return (f"the database {path} is damaged ({problem}): moved aside to {aside.name} (kept, "
            f"never written again); logging goes on in a new {path.name}; pymb salvage "
            f"{aside.name} NEW copies every row that can still be read")


def replace_damaged(path: Path) -> Path:
    """Move the damaged database aside and make a new one in its place, whose
    ids start above the old one's; returns where the damaged one is now."""
    floor = id_floor(path)
    aside = move_aside(path)
    create(path)
    seed_ids(path, floor)
    return aside


def set_aside_if_damaged(path: Path) -> str | None:
    """Check the database at ``path`` (``quick_check``, bounded in time); a
    damaged one is moved aside, never written, and a new one made in its
    place. Returns the line that says so (None: nothing found)."""
    problem = damage(path)
    if problem is None:
        return None
    return notice(path, replace_damaged(path), problem)


def damaged_error(path: Path, db: sqlite3.Connection | None, e: BaseException) -> OutputError:
    """Damage met while opening or writing (past the start's check): ``db`` is
    closed, the file moved aside (exit 5: the service's restart logs into a new
    file), and the error says so."""
    if db is not None:
        with contextlib.suppress(sqlite3.Error):
            db.close()
    try:
        aside = replace_damaged(path)
    except (OSError, sqlite3.Error) as moved:
        return OutputError(f"cannot write to {path}: the database is damaged ({e}) and could "
                           f"not be moved aside ({moved}); move it away by hand")
    return OutputError(f"cannot write to {path}: the database is damaged ({e}); moved aside "
                       f"to {aside.name} (kept); the batch being written was lost; the next "
                       f"start logs into a new {path.name}")
