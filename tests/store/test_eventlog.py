"""The last words of a run (the MQTT forwarder's drain and goodbye) go into
the database its writer closed, and never make a database that is not there."""

from __future__ import annotations

import sqlite3
import time
from pathlib import Path

from pymb.store import Event
from pymb.store.eventlog import append_events
from pymb.store.files import create


def _event(message: str) -> Event:
    return Event(time.time(), time.monotonic(), "mqtt", None, "mqtt", None, message)


def test_late_events_go_into_the_closed_database(tmp_path: Path) -> None:
    db = tmp_path / "log ?#%.sqlite"
    create(db)
    append_events(str(db), [_event("drained"), _event("goodbye")])
    con = sqlite3.connect(db)
    try:
        rows = con.execute("SELECT kind, message FROM events ORDER BY id").fetchall()
    finally:
        con.close()
    assert rows == [("mqtt", "drained"), ("mqtt", "goodbye")]


def test_a_database_that_is_gone_is_not_made_again(tmp_path: Path) -> None:
    """Moved away or deleted while the run ended: nothing is written, and no
    empty file takes its name."""
    for name in ("gone.sqlite", "gone ?#%.sqlite"):
        append_events(str(tmp_path / name), [_event("goodbye")])
    assert list(tmp_path.iterdir()) == []
