"""Waiting on what a logger process has committed to its SQLite file.

Tests that start ``pymb log`` wait for rows (the logger is up, a bus is
logging, an event was recorded) instead of sleeping a fixed time, which a slow
board or qemu-user overruns.
"""

from __future__ import annotations

import sqlite3
import subprocess
import time
from contextlib import closing
from pathlib import Path
from typing import Any


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
    deadline = time.monotonic() + timeout
    while True:
        n = count(db, sql, params)
        if n >= at_least:
            return n
        if proc is not None and proc.poll() is not None:
            raise AssertionError(f"the logger exited ({proc.returncode}) with {n} of "
                                 f"{at_least} rows for {sql!r} {params}")
        if time.monotonic() > deadline:
            raise AssertionError(f"{n} of {at_least} rows after {timeout} s for {sql!r} {params}")
        time.sleep(0.05)
