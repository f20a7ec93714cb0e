"""What the data commands (``export``, ``info``, ``plot``) share: the
database argument checked, UTC times parsed, a device looked up, output
files guarded. They parse and format; the store reads."""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
from collections.abc import Iterator
from datetime import UTC, datetime

from pymb.commands._common import parse_channels
from pymb.errors import InvalidArgument
from pymb.store import is_pymb_database, open_readonly, resolve_device
from pymb.store.damage import SQLITE_HEADER, damage, looks_like_pymb
from pymb.store.guard import sqlite_tables
from pymb.store.salvage import salvage

__all__ = ["check_database", "device_name", "parse_channels", "parse_time", "parse_times",
           "readable_database"]

#: seconds a reader (export, info) spends checking a database before reading it
READ_CHECK_SECONDS = 3.0


def check_database(path: str) -> None:
    """A one-line error unless ``path`` is a database pymb wrote."""
    if os.path.isdir(path):
        raise InvalidArgument(f"{path} is a directory, not a database")
    if not os.path.exists(path):
        raise InvalidArgument(f"no such database: {path}")
    try:
        with open(path, "rb") as f:
            head = f.read(16)
    except OSError as e:
        raise InvalidArgument(f"cannot read {path}: {e.strerror}") from None
    if head != SQLITE_HEADER or not is_pymb_database(path):
        if head == SQLITE_HEADER and "pymb_values" in (sqlite_tables(path) or ()):
            raise InvalidArgument(f"{path} is what pymb collect writes, not pymb log: query its "
                                  "pymb_values table (pymb_latest view) with SQL")
        raise InvalidArgument(f"{path} is not a database written by pymb")


def _damage(path: str) -> str | None:
    """What is wrong with the pymb database at ``path`` (None: nothing found,
    or not pymb's at all: check_database says so)."""
    if not os.path.isfile(path):
        return None
    try:
        with open(path, "rb") as f:
            head = f.read(16)
    except OSError:
        return None
    if head != SQLITE_HEADER:
        return "its header is damaged" if looks_like_pymb(path) else None
    return damage(path, READ_CHECK_SECONDS)


@contextlib.contextmanager
def readable_database(path: str, command: str) -> Iterator[str]:
    """The database to read for ``path``: itself, or for a damaged one every
    row that can be read of it, salvaged into a temporary file (the damaged
    file is only read), with what was skipped said on stderr."""
    problem = _damage(path)
    if problem is None:
        check_database(path)
        yield path
        return
    with tempfile.TemporaryDirectory(prefix="pymb-read-") as tmp:
        new = os.path.join(tmp, "salvaged.sqlite")
        result = salvage(path, new)
        print(f"pymb {command}: {path} is damaged ({problem}): reading every row that can "
              "be read", file=sys.stderr)
        for line in result.lines():
            print(f"pymb {command}: {line}", file=sys.stderr)
        yield new


def parse_time(flag: str, text: str | None) -> float | None:
    """An ISO 8601 time (UTC unless it says otherwise) as UTC seconds."""
    if text is None:
        return None
    try:  # '' is no time either: an error, never "no filter"
        t = datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError:
        raise InvalidArgument(f"{flag} needs an ISO 8601 time, got {text!r} (e.g. "
                              "2026-12-01T17:00:00Z; UTC unless it says otherwise)") from None
    if t.tzinfo is None:
        t = t.replace(tzinfo=UTC)
    return t.timestamp()


def parse_times(since: str | None, until: str | None) -> tuple[float | None, float | None]:
    """``--since`` and ``--until``, checked to make a span."""
    a, b = parse_time("--since", since), parse_time("--until", until)
    if a is not None and b is not None and b <= a:
        raise InvalidArgument(f"--until ({until}) must be after --since ({since})")
    return a, b


def device_name(path: str, wanted: str) -> str:
    """The name of the device ``wanted`` (a name or ``TYPE[:ADDRESS]``) in the database."""
    con = open_readonly(path)
    try:
        return resolve_device(con, wanted, path)[0]
    finally:
        con.close()
