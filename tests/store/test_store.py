"""The SQLite store on its own: size and age limits, reopening, schema."""

from __future__ import annotations

import contextlib
import sqlite3
import time
from array import array
from datetime import UTC, datetime
from pathlib import Path

from pymb.devices import CoolProStatus, CoolProTelemetry, decode_hub
from pymb.store import DeviceInfo, Event, Sample, SqliteSink

HUB = DeviceInfo("b", "/dev/null", "hub", 1, "hub-1")


def fill(sink: SqliteSink, n: int, t0: float) -> None:
    regs = array("H", range(700))
    for i in range(n):
        sink.write(Sample(HUB, t0 + i, float(i), decode_hub(regs)))
        if i % 50 == 49:
            sink.commit()
    sink.commit()


def test_size_limit_deletes_the_oldest(tmp_path: Path) -> None:
    db = tmp_path / "small.sqlite"
    sink = SqliteSink(db, max_bytes=1_000_000)
    fill(sink, 1500, time.time() - 1500)  # about 2.5 MB unbounded
    assert sink.trimmed > 0  # trimmed as the batches committed
    assert sink.retention.size() <= 1_000_000
    first, last, n = sink.db.execute(
        "SELECT MIN(id), MAX(id), COUNT(*) FROM samples").fetchone()
    assert last == 1500
    assert n == last - first + 1  # the newest are kept, in one run
    assert sink.db.execute("SELECT COUNT(*) FROM hub").fetchone()[0] == 100 * n
    sink.close()
    con = sqlite3.connect(db)
    assert con.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    con.close()


def test_write_batch_stores_what_write_stores(tmp_path: Path) -> None:
    # The logger hands runs of samples to write_batch (multi-row INSERTs):
    # the rows must be those that write() one by one makes, with and without
    # a size limit (which splits the statements and commits between them).
    cp = DeviceInfo("b", "/dev/null", "coolpro", 40, "coolpro-40")
    t0 = time.time() - 1000
    samples = []
    for i in range(150):
        regs = array("H", [(i * 7 + k) & 0xFFFF for k in range(700)])
        hub = decode_hub(regs, unsupported=("temperature2_c",) if i % 3 else ())
        samples.append(Sample(HUB, t0 + i, float(i), hub))
        samples.append(Sample(cp, t0 + i + 0.5, i + 0.5, CoolProTelemetry(
            24.0, 1.0, 12.0, 2.0, 30.0, i, CoolProStatus(i & 0x7F),
            array("H", [i, 0, 1, 0, 2, 0, i, 0]))))
    rows = {}
    for name, limit in (("one", None), ("batch", None), ("bounded", 50_000_000)):
        sink = SqliteSink(tmp_path / f"{name}.sqlite", max_bytes=limit)
        if name == "one":
            for s in samples:
                sink.write(s)
        else:
            sink.wal_budget = 256 * 1024 if limit else sink.wal_budget
            for k in range(0, len(samples), 64):
                sink.write_batch(samples[k:k + 64])
        sink.close()
        con = sqlite3.connect(tmp_path / f"{name}.sqlite")
        rows[name] = con.execute(
            "SELECT d.name, s.time_utc, s.monotonic, s.registers, s.unsupported "
            "FROM samples s JOIN devices d ON d.id = s.device_id ORDER BY s.id").fetchall()
        con.close()
    assert len(rows["one"]) == 300
    assert rows["batch"] == rows["one"]
    assert rows["bounded"] == rows["one"]


def test_age_limit_deletes_old_samples_and_events(tmp_path: Path) -> None:
    db = tmp_path / "aged.sqlite"
    sink = SqliteSink(db, max_age=100.0)
    now = time.time()
    fill(sink, 20, now - 200)  # 200..181 s old
    fill(sink, 10, now - 50)  # 50..41 s old
    sink.event(Event(now - 150, 0.0, "b", HUB, "timeout", None, "old"))
    sink.event(Event(now - 10, 0.0, "b", HUB, "timeout", None, "new"))
    sink.commit()
    assert sink.trim() == 20
    assert sink.db.execute("SELECT COUNT(*) FROM samples").fetchone()[0] == 10
    assert [m for (m,) in sink.db.execute("SELECT message FROM events")] == ["new"]
    sink.close()


def test_reopen_appends_and_keeps_devices(tmp_path: Path) -> None:
    db = tmp_path / "again.sqlite"
    for _ in range(2):
        sink = SqliteSink(db)
        fill(sink, 3, time.time())
        sink.close()
    con = sqlite3.connect(db)
    assert con.execute("SELECT COUNT(*) FROM samples").fetchone()[0] == 6
    assert con.execute("SELECT COUNT(*) FROM devices").fetchone()[0] == 1
    assert con.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    names = dict(con.execute("SELECT code, name FROM states").fetchall())
    assert names == {0: "value", 1: "offline", 2: "no_sensor", 3: "unsupported", 4: "not_read"}
    con.close()


def test_views_give_readable_utc_times(tmp_path: Path) -> None:
    db = tmp_path / "views.sqlite"
    sink = SqliteSink(db)
    fill(sink, 2, 1795413913.25)
    sink.event(Event(1795413913.5, 0.0, "b", HUB, "timeout", None, "late"))
    sink.close()
    con = sqlite3.connect(db)
    def utc(t: float) -> str:
        return datetime.fromtimestamp(t, UTC).strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + "Z"

    times = {t for (t,) in con.execute("SELECT time FROM hub_readings")}
    assert times == {utc(1795413913.25), utc(1795413914.25)}
    assert con.execute("SELECT time FROM event_log").fetchone()[0] == utc(1795413913.5)
    con.close()


def test_text_outputs_turn_write_errors_into_output_errors() -> None:
    import pytest

    from pymb.store import CsvSink, JsonlSink, OutputError

    for cls in (CsvSink, JsonlSink):
        sink = cls("/dev/full")  # every write: ENOSPC
        with pytest.raises(OutputError, match="No space"):  # noqa: PT012 (whichever call flushes)
            for _ in range(2000):  # past the buffer, whichever call flushes
                sink.event(Event(time.time(), 0.0, "b", HUB, "timeout", None, "x" * 100))
                sink.commit()
        with contextlib.suppress(OutputError):
            sink.close()


def test_size_limit_also_bounds_events_when_no_samples_come(tmp_path: Path) -> None:
    sink = SqliteSink(tmp_path / "outage.sqlite", max_bytes=1_000_000)
    for i in range(40_000):  # a long outage: one event per poll, no samples
        sink.event(Event(time.time(), float(i), "b", HUB, "timeout", None, "no reply " * 4))
        if i % 1000 == 999:
            sink.commit()
    sink.commit()
    assert sink.retention.size() <= 1_000_000
    newest = sink.db.execute("SELECT MAX(monotonic) FROM events").fetchone()[0]
    assert newest == 39_999.0  # the newest are kept
    sink.close()
