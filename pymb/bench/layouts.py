"""Storage layouts of a hub sweep compared: size, insert CPU, the documented queries.

``format2``  pymb's format: one ``samples`` row per sweep holding the 700
             registers once as a BLOB; decoded values through views.
``ints``     one row per channel with the 7 raw registers as INTEGER columns
             (no BLOB), decoded through a view.
``format1``  pymb's format before: the raw BLOB in ``samples`` and a decoded
             copy, 100 ``hub`` rows of REAL and state columns per sweep.

Each layout gets the same sweeps (the bench's simulated hub, its registers
moving a little from sweep to sweep) in a database file of its own, with
the same batching as ``pymb log``; the queries are timed on the result.
Also :func:`write_format1` makes a format-1 file, for the tests of reading
and refusing old databases.
"""

from __future__ import annotations

import os
import sqlite3
import statistics
import time
from array import array
from collections.abc import Callable
from typing import Any

from pymb.devices import HubReading, decode_hub
from pymb.devices.hubreading import BLOCKS, CHANNELS
from pymb.devices.readings import map_reading
from pymb.store import DeviceInfo, Sample, SqliteSink

__all__ = ["FORMAT1_SCHEMA", "LAYOUTS", "compare", "write_format1"]

LAYOUTS = ("format2", "ints", "format1")
_FIELDS = [b.name for b in BLOCKS]

#: pymb's format 1 (before format 2), as it created it
FORMAT1_SCHEMA = f"""
CREATE TABLE meta(key TEXT PRIMARY KEY, value TEXT);
CREATE TABLE devices(
    id INTEGER PRIMARY KEY, bus TEXT NOT NULL, port TEXT NOT NULL, type TEXT NOT NULL,
    address INTEGER NOT NULL, name TEXT NOT NULL, UNIQUE(bus, address, type));
CREATE TABLE samples(
    id INTEGER PRIMARY KEY, device_id INTEGER NOT NULL REFERENCES devices(id),
    time_utc REAL NOT NULL, monotonic REAL NOT NULL, registers BLOB NOT NULL);
CREATE INDEX samples_time ON samples(time_utc);
CREATE TABLE coolpro(sample_id INTEGER PRIMARY KEY REFERENCES samples(id),
    input_voltage_v REAL, input_current_a REAL, output_voltage_v REAL, output_current_a REAL,
    temperature_c REAL, uptime_s INTEGER, status INTEGER);
CREATE TABLE hub(
    sample_id INTEGER NOT NULL REFERENCES samples(id), channel INTEGER NOT NULL,
    {", ".join(f"{n} REAL" for n in _FIELDS)},
    {", ".join(f"{n}_state INTEGER" for n in _FIELDS)},
    PRIMARY KEY(sample_id, channel)) WITHOUT ROWID;
CREATE TABLE states(code INTEGER PRIMARY KEY, name TEXT NOT NULL);
CREATE TABLE events(
    id INTEGER PRIMARY KEY, time_utc REAL NOT NULL, monotonic REAL NOT NULL, bus TEXT,
    device_id INTEGER REFERENCES devices(id), kind TEXT NOT NULL, code INTEGER,
    message TEXT NOT NULL);
CREATE INDEX events_time ON events(time_utc);
CREATE VIEW hub_readings AS
    SELECT strftime('%Y-%m-%d %H:%M:%f', s.time_utc, 'unixepoch') AS time, s.time_utc,
           d.name AS device, d.address, h.*
      FROM hub h JOIN samples s ON s.id = h.sample_id JOIN devices d ON d.id = s.device_id;
INSERT INTO meta VALUES ('schema_version', '1');
INSERT INTO meta VALUES ('pymb_version', '0.1.0');
"""

_INTS_SCHEMA = f"""
CREATE TABLE devices(id INTEGER PRIMARY KEY, name TEXT NOT NULL);
CREATE TABLE samples(id INTEGER PRIMARY KEY, device_id INTEGER NOT NULL,
    time_utc REAL NOT NULL, monotonic REAL NOT NULL, unsupported INTEGER NOT NULL DEFAULT 0);
CREATE INDEX samples_time ON samples(time_utc);
CREATE TABLE hub(sample_id INTEGER NOT NULL, channel INTEGER NOT NULL,
    {", ".join(f"r{b} INTEGER" for b in range(len(_FIELDS)))},
    PRIMARY KEY(sample_id, channel)) WITHOUT ROWID;
CREATE VIEW hub_readings AS
    SELECT strftime('%Y-%m-%d %H:%M:%f', s.time_utc, 'unixepoch') AS time, s.time_utc,
           d.name AS device, h.channel,
           CASE WHEN r0 = 65535 THEN NULL WHEN r0 >= 32768 THEN -(r0 - 32768) / 10.0
                ELSE r0 / 10.0 END AS temperature_c,
           CASE WHEN r1 IN (65535, 32768) THEN NULL ELSE r1 / 10.0 END AS humidity_pct
      FROM samples s JOIN devices d ON d.id = s.device_id JOIN hub h ON h.sample_id = s.id;
"""


def write_format1(path: str, readings: list[tuple[float, HubReading]],
                  name: str = "hub-1") -> None:
    """A database of pymb's format 1 holding these hub readings (at these UTC times)."""
    con = sqlite3.connect(path, isolation_level=None)
    try:
        con.executescript(FORMAT1_SCHEMA)
        con.execute("INSERT INTO devices VALUES (1, 'bus1', '/dev/null', 'hub', 1, ?)", (name,))
        con.execute("BEGIN")
        for t, r in readings:
            _write_format1(con, t, r)
        con.execute("COMMIT")
    finally:
        con.close()


def _be(regs: array[int]) -> bytes:
    a = array("H", regs)
    a.byteswap()
    return a.tobytes()


def _write_format1(con: sqlite3.Connection, t: float, r: HubReading) -> None:
    sid = con.execute("INSERT INTO samples(device_id, time_utc, monotonic, registers) "
                      "VALUES (1, ?, ?, ?)", (t, t, _be(r.registers))).lastrowid
    c = r.channels
    values = [r.values[b * c:(b + 1) * c].tolist() for b in range(len(_FIELDS))]
    states = [r.raw_states[b * c:(b + 1) * c].tolist() for b in range(len(_FIELDS))]
    con.executemany(f"INSERT INTO hub VALUES ({', '.join('?' * (2 + 2 * len(_FIELDS)))})",
                    zip([sid] * c, range(1, c + 1), *values, *states, strict=True))


def _write_ints(con: sqlite3.Connection, t: float, r: HubReading) -> None:
    sid = con.execute("INSERT INTO samples(device_id, time_utc, monotonic, unsupported) "
                      "VALUES (1, ?, ?, ?)", (t, t, r.unsupported_mask)).lastrowid
    regs, n = r.registers, CHANNELS
    con.executemany("INSERT INTO hub VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
                    [(sid, ch + 1, *(regs[b * n + ch] for b in range(len(_FIELDS))))
                     for ch in range(r.channels)])


def _sweeps(first: array[int], n: int) -> list[HubReading]:
    """``n`` sweeps: the simulated hub's registers, one channel's values moving a
    little each sweep (as a real hub's do between its sensors' reports)."""
    out = []
    regs = array("H", first)
    for i in range(n):
        ch = i % CHANNELS
        for b in (0, 1):
            k = b * CHANNELS + ch
            if regs[k] not in (0xFFFF, 0x8000):
                regs[k] = (regs[k] & 0x8000) | ((regs[k] & 0x7FFF) + (1 if i % 2 else -1)) & 0x7FFF
        out.append(decode_hub(array("H", regs)))
    return out


QUERIES = {
    "latest 6 rows of channels 1-3":
        "SELECT time, device, channel, temperature_c, humidity_pct FROM hub_readings "
        "WHERE channel <= 3 ORDER BY time_utc DESC LIMIT 6",
    "channel 3 at time t":
        "SELECT time, temperature_c FROM hub_readings WHERE device = 'hub-1' AND channel = 3 "
        "AND time_utc <= :t ORDER BY time_utc DESC LIMIT 1",
    "channel 3 over 60 s":
        "SELECT AVG(temperature_c) FROM hub_readings WHERE device = 'hub-1' AND channel = 3 "
        "AND time_utc BETWEEN :t - 60 AND :t",
}


def _pages(path: str) -> int:
    con = sqlite3.connect(path)
    try:
        con.execute("PRAGMA wal_checkpoint(TRUNCATE)")
        count = con.execute("PRAGMA page_count").fetchone()[0]
        size = con.execute("PRAGMA page_size").fetchone()[0]
        return int(count * size)
    finally:
        con.close()


def compare(first: array[int], where: str, n: int = 3000,
            progress: Callable[[str], None] | None = None) -> list[dict[str, Any]]:
    """Write ``n`` sweeps in every layout; size, insert CPU and query times."""
    sweeps = _sweeps(first, n)
    # format 2 is handed what the logger hands its store: the map readings of the sweeps
    readings = [map_reading(r) for r in sweeps]
    t0 = 1_800_000_000.0
    times = [t0 + i / 7.6 for i in range(n)]  # a 115200 bus at wire speed
    rows = []
    for layout in LAYOUTS:
        if progress:
            progress(f"logger: layout {layout}, {n} sweeps")
        path = os.path.join(where, f"layout-{layout}.sqlite")
        c0 = time.process_time()
        if layout == "format2":
            sink = SqliteSink(path)
            info = DeviceInfo("bus1", "/dev/null", "hub", 1, "hub-1")
            for i, (t, reading) in enumerate(zip(times, readings, strict=True)):
                sink.write(Sample(info, t, t, reading))
                if i % 4 == 3:
                    sink.commit()
            sink.close()
        else:
            con = sqlite3.connect(path, isolation_level=None)
            con.execute("PRAGMA journal_mode = WAL")
            con.execute("PRAGMA synchronous = NORMAL")
            if layout == "format1":
                con.executescript(FORMAT1_SCHEMA)
                con.execute("INSERT INTO devices VALUES (1, 'b', '/dev/null', 'hub', 1, 'hub-1')")
                write = _write_format1
            else:
                con.executescript(_INTS_SCHEMA)
                con.execute("INSERT INTO devices VALUES (1, 'hub-1')")
                write = _write_ints
            for i, (t, r) in enumerate(zip(times, sweeps, strict=True)):
                if i % 4 == 0:
                    con.execute("BEGIN")
                write(con, t, r)
                if i % 4 == 3:
                    con.execute("COMMIT")
            if con.in_transaction:
                con.execute("COMMIT")
            con.close()
        cpu = time.process_time() - c0
        size = _pages(path)
        con = sqlite3.connect(path)
        queries = {}
        t = times[n // 2]
        for what, q in QUERIES.items():
            runs = []
            for _ in range(5):
                q0 = time.perf_counter()
                con.execute(q, {"t": t}).fetchall()
                runs.append(time.perf_counter() - q0)
            plan = " / ".join(r[3] for r in con.execute("EXPLAIN QUERY PLAN " + q, {"t": t}))
            queries[what] = {"ms": 1e3 * statistics.median(runs), "plan": plan}
        con.close()
        rows.append({"layout": layout, "bytes_per_sweep": size / n,
                     "insert_cpu_us": 1e6 * cpu / n, "queries": queries})
    return rows
