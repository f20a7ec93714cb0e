"""Events written to a database its writer has closed: what happens after
the log ends (the MQTT forwarder's drain and goodbye) still goes on record."""

from __future__ import annotations

import contextlib
import sqlite3
from collections.abc import Sequence
from pathlib import Path

from pymb.store.records import Event

__all__ = ["EVENT_INSERT", "append_events"]

#: the one statement that records an event (its device as its id in ``devices``)
EVENT_INSERT = ("INSERT INTO events(time_utc, monotonic, bus, device_id, kind, code, message) "
                "VALUES (?, ?, ?, ?, ?, ?, ?)")


def append_events(path: str, events: Sequence[Event]) -> None:
    """Add ``events`` (of no device) to the pymb database at ``path`` in one
    transaction, waiting up to 10 s for another writer. A database that
    cannot take them (gone, locked, read-only) keeps what it has: these are
    the last words of a run, said on stderr too."""
    if not events:
        return
    with contextlib.suppress(sqlite3.Error):
        # mode=rw: a database that is gone is not made again (an empty file)
        con = sqlite3.connect(Path(path).absolute().as_uri() + "?mode=rw", uri=True,
                              timeout=10)
        try:
            with con:
                con.executemany(EVENT_INSERT, [
                    (e.time_utc, e.monotonic, e.bus, None, e.kind, e.code, e.message)
                    for e in events])
        finally:
            con.close()
