"""No unsent sample leaves without a record, whether or not a broker was
ever reached: a board commissioned before its network works logs with
``--mqtt`` and a size bound; every sample the bound deletes is counted in
a ``trim`` event, and the trims never delete the events that say so.

Real processes: ``pymb log`` against a simulated hub on Modbus TCP in its
own process, forwarding to an address where no broker listens.
"""

from __future__ import annotations

import socket
import sqlite3
import subprocess
import time
from array import array
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from conftest import PYMB, PYMB_ENV, wait_until

from pymb.devices import decode_hub
from pymb.sim import SimulatorProcess
from pymb.store import DeviceInfo, Event, Sample, SqliteSink


@pytest.fixture
def hub() -> Iterator[str]:
    """A simulated hub on Modbus TCP in its own process: HOST:PORT."""
    sim = SimulatorProcess(["hub:1", "--tcp", "127.0.0.1:0"], quiet=True).start()
    try:
        yield sim.endpoint
    finally:
        sim.stop()


def _closed_port() -> int:
    """A loopback port where nothing listens (a broker not reachable yet)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _query(db: Path, sql: str) -> list[tuple[Any, ...]]:
    if not db.exists():
        return []
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=10)
    try:
        return con.execute(sql).fetchall()
    except sqlite3.OperationalError:  # the schema not made yet
        return []
    finally:
        con.close()


def _first_id(db: Path) -> int:
    rows = _query(db, "SELECT MIN(id) FROM samples")
    return int(rows[0][0] or 0) if rows else 0


def test_samples_trimmed_before_a_broker_was_ever_reached_are_recorded(
        hub: str, tmp_path: Path) -> None:
    db = tmp_path / "board.sqlite"
    url = f"mqtt://127.0.0.1:{_closed_port()}"
    proc = subprocess.Popen([*PYMB, "log", "hub:1", "--tcp", hub, "--interval", "0",
                             "--out", str(db), "--max-mb", "1", "--mqtt", url,
                             "--mqtt-node", "gw-new", "--quiet"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            env=PYMB_ENV)
    try:
        # the bound trims (1 MB: a few hundred hub sweeps), more than once
        wait_until(lambda: _first_id(db) > 1000, "1,000 samples trimmed", 180,
                   alive=lambda: proc.poll() is None, every=0.2)
    finally:
        if proc.poll() is None:
            proc.terminate()
        _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    assert _query(db, "SELECT COUNT(*) FROM outbox WHERE sample_id > 0") == [(0,)]
    first = _first_id(db)
    trims = _query(db, "SELECT code, message FROM events WHERE kind = 'trim' ORDER BY id")
    assert trims, "samples never sent were deleted without a record"
    # every deleted sample is counted, once (all of them unsent)
    assert sum(int(code) for code, _ in trims) == first - 1
    assert all("not yet forwarded" in str(m) for _, m in trims)


def test_the_trim_keeps_the_newest_record_of_unsent_samples(tmp_path: Path) -> None:
    """A long outage logs events and no samples: the size bound deletes the
    oldest events, the records of unsent samples last, and never the newest
    of them."""
    db = tmp_path / "outage.sqlite"
    sink = SqliteSink(db, max_bytes=1_000_000)
    sink.db.execute("CREATE TABLE outbox(name TEXT PRIMARY KEY, sample_id INTEGER NOT NULL)")
    hub = DeviceInfo("b", "p", "hub", 1, "hub-1")
    reading = decode_hub(array("H", range(700)))
    now = time.time()
    for i in range(1500):  # past the bound: trims, each recorded
        sink.write(Sample(hub, now - 3000 + i, float(i), reading))
        if i % 20 == 19:
            sink.commit()
    (records,) = sink.db.execute("SELECT COUNT(*) FROM events WHERE kind = 'trim'").fetchone()
    assert records >= 1
    text = "x" * 2000
    for i in range(2000):  # then only events (a device down for days): 4 MB of them
        sink.event(Event(now + i, 1500.0 + i, "b", None, "fault", 1, f"{i} {text}"))
        if i % 20 == 19:
            sink.commit()
    sink.close()
    con = sqlite3.connect(db)
    try:
        kinds = [k for (k,) in con.execute("SELECT kind FROM events")]
        trimmed = con.execute("SELECT MIN(id) FROM events WHERE kind = 'fault'").fetchone()[0]
    finally:
        con.close()
    assert trimmed > 1, "the bound deleted no event: nothing was tested"
    assert "trim" in kinds, "the trims deleted every record of the unsent samples"
