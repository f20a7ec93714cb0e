"""Waiting on what a logger process has committed to its SQLite file (and a
small database to start from).

Tests that start ``pymb log`` wait for rows (the logger is up, a bus is
logging, an event was recorded) instead of sleeping a fixed time, which a slow
board or qemu-user overruns.
"""

from __future__ import annotations

import sqlite3
import subprocess
from array import array
from contextlib import closing
from pathlib import Path
from typing import Any

from conftest import wait_until

from pymb.devices import decode_hub
from pymb.store import DeviceInfo, Sample, SqliteSink


def count(db: Path, sql: str, params: tuple[Any, ...] = ()) -> int:
    """The integer ``sql`` selects; 0 while the file or its tables do not exist yet."""
    if not db.exists():
        return 0
    try:
        with closing(sqlite3.connect(db, timeout=10)) as con:
            row = con.execute(sql, params).fetchone()
    except sqlite3.OperationalError:
        return 0  # the logger has not created its schema yet
    return int(row[0] or 0) if row else 0


def wait_for(db: Path, sql: str, params: tuple[Any, ...] = (), at_least: int = 1,
             proc: subprocess.Popen[Any] | None = None, timeout: float = 60.0) -> int:
    """Poll ``count(db, sql, params)`` until it reaches ``at_least``; return it.

    Fails when ``proc`` (the logger) exits first or after ``timeout`` seconds.
    """
    seen = 0

    def enough() -> bool:
        nonlocal seen
        seen = count(db, sql, params)
        return seen >= at_least

    def what() -> str:
        exited = (f" (the logger exited {proc.returncode})"
                  if proc is not None and proc.returncode is not None else "")
        return f"{at_least} rows for {sql!r} {params}: {seen}{exited}"

    wait_until(enough, what, timeout, every=0.05,
               alive=None if proc is None else lambda: proc.poll() is None)
    return seen


def one_sample_database(path: Path) -> None:
    """A pymb database at ``path`` holding one hub sample (every register 0)."""
    sink = SqliteSink(path)
    sink.write(Sample(DeviceInfo("b", "p", "hub", 1, "hub-1"), 1_800_000_000.0, 1.0,
                      decode_hub(array("H", [0] * 700))))
    sink.close()
