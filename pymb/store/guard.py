"""Output-file guards: pymb never writes into a file of another kind."""

from __future__ import annotations

import os
import sqlite3

from pymb.errors import InvalidArgument
from pymb.store.damage import SQLITE_HEADER, looks_like_pymb
from pymb.store.readonly import open_readonly
from pymb.store.schema import schema_version
from pymb.store.text import CSV_COLUMNS

__all__ = ["check_output", "is_pymb_database", "sqlite_tables"]

#: file name endings -> the output format they say
_SUFFIXES = {".csv": "csv", ".jsonl": "jsonl", ".ndjson": "jsonl", ".json": "jsonl",
             ".sqlite": "sqlite", ".sqlite3": "sqlite", ".db": "sqlite"}


def _named_like(fmt: str, path: str, choosable: bool) -> None:
    """Refuse ``fmt`` into a file whose name says another format: a newcomer's
    ``pymb log ... --out readings.csv`` without ``--format csv`` would write a
    SQLite database under a CSV's name."""
    said = _SUFFIXES.get(os.path.splitext(path)[1].lower())
    if said is None or said == fmt:
        return
    kind = {"csv": "CSV", "jsonl": "JSON Lines", "sqlite": "SQLite"}[said]
    how = (f"give --format {said} (in TOML: format = \"{said}\" under [output]), or another "
           "name" if choosable else "give it another name")
    raise InvalidArgument(f"{path} is named like a {kind} file but the format is {fmt}: {how}")


def check_output(fmt: str, path: str, *, choosable: bool = True) -> None:
    """Refuse to write ``fmt`` into an existing file of another kind: CSV or
    JSON Lines appended to a database (or to someone's document), SQLite
    tables added to a file that is not a pymb database; nor, into a new
    file, a format its name says it is not (SQLite into ``readings.csv``, CSV
    into ``data.sqlite``). ``choosable``: the user may choose the format
    (``--format``), which the message then names. SQLite is never written to
    stdout (``-``)."""
    if path == "-":
        if fmt == "sqlite":
            raise InvalidArgument("SQLite needs a file; " + (
                "use --format csv, jsonl or influx for stdout" if choosable
                else "give --out a file name"))
        return
    if not os.path.exists(path):
        _named_like(fmt, path, choosable)
        return
    if os.path.isdir(path):
        raise InvalidArgument(f"{path} is a directory; give a file name")
    if not os.path.isfile(path) or os.path.getsize(path) == 0:
        return
    try:
        with open(path, "rb") as f:
            head = f.read(512)
    except OSError as e:
        raise InvalidArgument(f"cannot read {path}: {e.strerror}") from None
    sqlite = head.startswith(SQLITE_HEADER)
    first = head.split(b"\n", 1)[0].rstrip(b"\r")
    if fmt == "sqlite":
        if looks_like_pymb(path) and (not sqlite or not is_pymb_database(path)):
            return  # a damaged pymb database: the writer moves it aside
        if not sqlite:
            raise InvalidArgument(f"{path} exists and is not a SQLite database: refusing to "
                                  "write into it; choose another --out")
        if not is_pymb_database(path):
            what = ("what pymb collect writes, not pymb log" if "pymb_values" in
                    (sqlite_tables(path) or ()) else "a SQLite database not written by pymb")
            raise InvalidArgument(f"{path} is {what}: refusing to add to it; "
                                  "choose another --out")
        return
    if fmt == "csv" and not sqlite and first.decode("utf-8", "replace") == ",".join(CSV_COLUMNS):
        return
    if fmt == "jsonl" and not sqlite and head.startswith(b'{"time_utc": '):
        return
    if fmt == "influx" and not sqlite and head.startswith(b"pymb_"):  # pymb's measurements
        return
    name = _NAMES.get(fmt, fmt)
    if sqlite:
        raise InvalidArgument(f"{path} is a SQLite database: refusing to append {name} to it; "
                              "choose another --out")
    wide = ",".join(CSV_COLUMNS[:6]) + ","
    if fmt == "csv" and first.decode("utf-8", "replace").startswith(wide):
        raise InvalidArgument(f"{path} is a wide CSV (pymb export --layout wide), whose columns "
                              "the long rows pymb log writes do not fit: refusing to append to "
                              "it; choose another --out")
    raise InvalidArgument(f"{path} exists and is not {name} that pymb wrote: refusing to append "
                          "to it; choose another --out")


_NAMES = {"csv": "CSV", "jsonl": "JSON Lines", "influx": "InfluxDB line protocol"}


def is_pymb_database(path: str) -> bool:
    """True if ``path`` is a SQLite database pymb wrote (or an empty one)."""
    try:
        db = open_readonly(path)
        try:
            return schema_version(db) is not None  # the one test of "is this pymb's"
        finally:
            db.close()
    except (sqlite3.Error, InvalidArgument):
        return False


def sqlite_tables(path: str) -> set[str] | None:
    """The tables of the SQLite file at ``path``, read without writing (None:
    not a SQLite file, or unreadable): whose file it is, ``pymb collect``'s
    (``pymb_values``) or another program's."""
    try:
        db = open_readonly(path)
        try:
            return {str(n) for (n,) in db.execute(
                "SELECT name FROM sqlite_master WHERE type = 'table'")}
        finally:
            db.close()
    except (sqlite3.Error, InvalidArgument):
        return None
