"""The writer and the forwarder share the database file: the forwarder's
outbox cursor, written between two of the writer's statements, never costs
the writer its batch."""

from __future__ import annotations

import sqlite3
from array import array
from pathlib import Path

from pymb.devices import CoolProStatus, CoolProTelemetry
from pymb.store import DeviceInfo, Outbox, Sample, SqliteSink


def _sample(name: str, t: float) -> Sample:
    data = CoolProTelemetry(24.5, 2.45, 24.0, 2.41, 26.1, 1, CoolProStatus(0),
                            array("H", [0] * 8))
    return Sample(DeviceInfo("bus1", "/dev/null", "coolpro", 40, name), t, t, data)


def test_a_cursor_written_between_the_writers_read_and_write_costs_no_batch(
        tmp_path: Path) -> None:
    """The writer's transaction reads (is this device known?) before it writes.
    The forwarder moving its cursor at that moment, from its own connection,
    must not make the writer's insert fail with 'database is locked': the
    writer holds the write lock from the start of its transaction, and the
    forwarder is the one that waits (and retries its small write later)."""
    db = tmp_path / "data.sqlite"
    sink = SqliteSink(db)
    sink.write(_sample("psu-a", 1.0))
    sink.commit()
    outbox = Outbox(str(db))
    outbox.db.execute("PRAGMA busy_timeout = 50")  # do not wait long in this test
    tried: list[str] = []

    def forwarder_moves_its_cursor(stmt: str) -> None:
        if stmt.startswith("INSERT INTO devices") and not tried:
            try:
                outbox.set_cursor("mqtt://127.0.0.1:1883/plain/n", 1)
                tried.append("written")
            except sqlite3.OperationalError as e:
                tried.append(str(e))

    sink.db.set_trace_callback(forwarder_moves_its_cursor)
    sink.write(_sample("psu-b", 2.0))  # a new device: read, then insert
    sink.commit()
    sink.db.set_trace_callback(None)
    assert tried == ["database is locked"]  # the forwarder waited, not the writer
    outbox.set_cursor("mqtt://127.0.0.1:1883/plain/n", 1)  # and gets through afterwards
    assert outbox.cursor("mqtt://127.0.0.1:1883/plain/n") == 1
    assert [r[0] for r in sink.db.execute("SELECT name FROM devices ORDER BY id")] == [
        "psu-a", "psu-b"]
    outbox.close()
    sink.close()
