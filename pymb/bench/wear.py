"""SD wear: what logging writes to the disk, beside what it stores.

``python -m pymb.bench.wear MODE KIND PORT INTERVAL SECONDS DB`` logs one
device (``hub`` or ``coolpro``, on a simulator's pseudo-terminal emulating
a 115200 baud line) for SECONDS, at wire speed (INTERVAL 0) or every
INTERVAL seconds, and prints one JSON line: samples, the bytes this process
had written to the block layer (``write_bytes`` of ``/proc/self/io``: pages
it dirtied, what writeback sends to the disk), and the bytes the samples
take in the database (``dbstat``: the bytes in use on their table and index
pages), and the WAL frames (pages) each commit wrote (:class:`WalFrames`).
The file and its schema are made before the count starts.

MODE ``pymb`` is ``pymb log`` (:class:`pymb.logger.Logger` and its SQLite
sink, as configured by default); ``naive`` is the logger everyone writes
first: SQLite's defaults (rollback journal, ``synchronous=FULL``, 4 KB
pages), one INSERT and one commit per sample.

:func:`run_wear` runs the worker for each kind, interval and mode, each
under ``strace -c`` (when installed) to count its ``fsync``/``fdatasync``
calls; ``--quick`` runs them all side by side, forked, without strace.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import sqlite3
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from typing import Any, BinaryIO

__all__ = ["WalFrames", "main", "run_wear", "targets"]

ADDRESSES = {"hub": 1, "coolpro": 40}
#: the commit interval of the extra runs at 1 s (each kind): what a longer loss bound buys
LONGER_COMMIT = 10.0
#: bytes a device polled every second may have written per second (two 4 KB pages)
PER_SECOND_GOAL = 8 * 1024
_NAIVE_SCHEMA = """
CREATE TABLE IF NOT EXISTS samples(id INTEGER PRIMARY KEY, device TEXT NOT NULL,
                                   time_utc REAL NOT NULL, registers BLOB NOT NULL);
CREATE INDEX IF NOT EXISTS samples_time ON samples(time_utc);
"""


def _disk_temp() -> str:
    """A temporary folder on a real disk: the system's, unless it is a tmpfs
    (nothing reaches the block layer there), then ``/var/tmp``."""
    where = tempfile.gettempdir()
    try:
        with open("/proc/mounts") as f:
            mounts = [line.split()[1:3] for line in f]
    except OSError:
        return where
    real = os.path.realpath(where)
    best = max((m for m in mounts if real == m[0] or real.startswith(m[0].rstrip("/") + "/")),
               key=lambda m: len(m[0]), default=None)
    return "/var/tmp" if best is not None and best[1] == "tmpfs" else where


def _write_bytes() -> int:
    with open("/proc/self/io") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("write_bytes"))


def _stored(db: str, tables: Sequence[str]) -> int:
    con = sqlite3.connect(db)
    try:
        marks = ", ".join("?" * len(tables))
        return int(con.execute(f"SELECT COALESCE(SUM(pgsize - unused), 0) FROM dbstat "
                               f"WHERE name IN ({marks})", tuple(tables)).fetchone()[0])
    finally:
        con.close()


#: (write_bytes, samples stored, monotonic time) just after the run's first
#: commit: what comes after is the steady state (the start's own writes left out)
_FIRST: list[tuple[int, int, float]] = []
_COMMIT: list[float] = []  #: the commit interval asked for, if not the default


class WalFrames:
    """The frames each commit appended to a database's WAL, read from their
    headers after each commit (a 32-byte file header with the page size and
    the salt; each frame a 24-byte header, the page number, the database's
    size in pages on a commit's last frame, else 0, and the salt, then the
    page). A checkpoint's reset starts the WAL over with a new salt."""

    def __init__(self, db: str) -> None:
        self.path = db + "-wal"
        self.frames = 0  #: frames appended since the first count
        self.commits = 0  #: commits among them
        self._at = 0
        self._salt = b""

    def count(self) -> None:
        """Count the frames appended since the last call."""
        try:
            with open(self.path, "rb") as f:
                self._count(f)
        except OSError:
            return

    def _count(self, f: BinaryIO) -> None:
        head = f.read(32)
        if len(head) < 32:
            return
        page, salt = int.from_bytes(head[8:12], "big"), head[16:24]
        if salt != self._salt:
            self._salt, self._at = salt, 32
        while True:
            f.seek(self._at)
            frame = f.read(24)
            if len(frame) < 24 or frame[8:16] != salt:
                return
            self.frames += 1
            self.commits += int.from_bytes(frame[4:8], "big") != 0
            self._at += 24 + page


_WAL: list[WalFrames] = []  #: the run's WAL, counted from the end of its first commit


def _pymb(kind: str, port: str, interval: float, seconds: float, db: str) -> int:
    from pymb.logger import BusConfig, DeviceConfig, LogConfig, Logger
    from pymb.store import SqliteSink

    class CountingSink(SqliteSink):
        def commit(self) -> None:
            super().commit()
            if _FIRST:
                _WAL[0].count()
            elif self.stored:
                _FIRST.append((_write_bytes(), self.stored, time.monotonic()))
                _WAL.append(WalFrames(db))
                _WAL[0].count()
                _WAL[0].frames = _WAL[0].commits = 0

    bus = BusConfig(kind, port, None, 115200, "N", 2.0, interval,
                    [DeviceConfig(kind, ADDRESSES[kind])])
    cfg = LogConfig([bus], "sqlite", db, commit_interval=_COMMIT[0] if _COMMIT else None)
    return Logger(cfg, sink=CountingSink(db)).run(seconds).samples


def _naive(kind: str, port: str, interval: float, seconds: float, db: str) -> int:
    from pymb import RtuClient
    from pymb.devices.deviceconfig import DeviceConfig
    from pymb.store.schema import wire_bytes

    client = RtuClient(port, 115200, timeout=2.0)
    client.connect()
    dev = DeviceConfig(kind, ADDRESSES[kind])  # read as pymb log reads it: its map's group
    read_group, group = dev.open(client)[1], dev.groups[0]
    con = sqlite3.connect(db, isolation_level=None)
    con.executescript(_NAIVE_SCHEMA)
    n = 0
    start = time.monotonic()
    try:
        while (now := time.monotonic()) < start + seconds:
            data = read_group(group)
            con.execute("BEGIN")
            con.execute("INSERT INTO samples(device, time_utc, registers) VALUES (?, ?, ?)",
                        (kind, time.time(), wire_bytes(data.registers)))
            con.execute("COMMIT")
            n += 1
            if n == 1:
                _FIRST.append((_write_bytes(), n, time.monotonic()))
            if interval > 0:
                time.sleep(max(0.0, start + n * interval - time.monotonic()))
            del now
    finally:
        con.close()
        client.close()
    return n


def _prepare(mode: str, db: str) -> None:
    """Make the database and its schema (nothing if it is made already)."""
    if mode == "pymb":
        from pymb.store import SqliteSink
        SqliteSink(db).close()
    else:
        con = sqlite3.connect(db)
        try:
            con.executescript(_NAIVE_SCHEMA)
        finally:
            con.close()


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the worker."""
    args = list(sys.argv[1:] if argv is None else argv)
    if len(args) not in (6, 7) or args[0] not in ("pymb", "naive") or \
            args[1] not in ADDRESSES:
        print("usage: python -m pymb.bench.wear pymb|naive hub|coolpro PORT INTERVAL "
              "SECONDS DB [COMMIT_INTERVAL]", file=sys.stderr)
        return 2
    if len(args) == 7:
        _COMMIT.append(float(args[6]))
    mode, kind, port, interval, seconds, db = args[0], args[1], args[2], float(args[3]), \
        float(args[4]), args[5]
    # Everything imported and the file made first: compiled modules and the
    # schema are not the samples' cost.
    import pymb.devices
    import pymb.logger
    import pymb.store.schema  # noqa: F401
    _prepare(mode, db)
    w0 = _write_bytes()
    t0 = time.monotonic()
    samples = (_pymb if mode == "pymb" else _naive)(kind, port, interval, seconds, db)
    elapsed = time.monotonic() - t0
    w2, t2 = _write_bytes(), time.monotonic()
    written = w2 - w0
    # (counted before this reader opens the file: its own -shm is not the logger's)
    stored = _stored(db, ("samples", "samples_time", "hub_changes"))
    w1, n1, t1 = _FIRST[0] if _FIRST else (w0, 0, t0)
    steady = None if samples <= n1 else (w2 - w1) / (
        (samples - n1) * stored / max(1, samples))
    # bytes written per second from the first commit on (the 1 Hz goal)
    steady_bps = None if samples <= n1 else (w2 - w1) / max(1e-9, t2 - t1)
    # WAL frames (a page each) per commit, from the first commit on (pymb only)
    frames = None if not _WAL or not _WAL[0].commits else _WAL[0].frames / _WAL[0].commits
    print(json.dumps({"mode": mode, "kind": kind, "interval": interval, "samples": samples,
                      "elapsed": elapsed, "written": written, "stored": stored,
                      "steady": steady, "steady_bps": steady_bps,
                      "wal_frames_per_commit": frames}), flush=True)
    return 0


def _syncs(path: str) -> int | None:
    """fsync + fdatasync calls in an ``strace -c`` summary."""
    try:
        with open(path) as f:
            text = f.read()
    except OSError:
        return None
    n = 0
    for line in text.splitlines():
        m = re.match(r"\s*[\d.]+\s+[\d.]+\s+\d+\s+(\d+)\s+(?:\d+\s+)?(fsync|fdatasync)\s*$", line)
        if m:
            n += int(m.group(1))
    return n


def run_wear(opts: Any, children: Any) -> list[dict[str, Any]]:
    """Every kind at wire speed and at a 1 s interval, pymb and the naive
    logger side by side (and, at 1 s, each kind committed every
    LONGER_COMMIT seconds: what a longer bound buys); each row with bytes
    written and stored per sample, their ratio, and fdatasyncs per second."""
    strace = shutil.which("strace")
    # A run holds many commits of each kind (the quick plan only checks the machinery).
    wire_s, slow_s = (3.0, 3.0) if opts.quick else (300.0, 600.0)
    rows: list[dict[str, Any]] = []
    # --quick: every run side by side (its figures only show the machinery works)
    plans = [(0.0, wire_s), (1.0, slow_s)]
    batches = [plans] if opts.quick else [[p] for p in plans]
    with tempfile.TemporaryDirectory(prefix="pymb-bench-wear-", dir=_disk_temp()) as where:
        for batch in batches:
            runs: list[tuple[float, float, str, str, float | None]] = []
            for interval, seconds in batch:
                what = "wire speed" if interval == 0 else f"a {interval:g} s interval"
                opts.say(f"logger: SD wear at {what}, {seconds:g} s")
                runs += [(interval, seconds, mode, kind, None)
                         for kind in ADDRESSES for mode in ("pymb", "naive")]
                if interval:  # what the longer bound for a small batch buys
                    runs += [(interval, seconds, "pymb", kind, LONGER_COMMIT)
                             for kind in ADDRESSES]
            sims = children.sims([[f"{kind}:{ADDRESSES[kind]},dynamic=0", "--baud", "115200",
                                   "--seed", "0"] for _, _, _, kind, _ in runs])
            procs: list[tuple[Any, str, float | None, float]] = []
            for (interval, seconds, mode, kind, commit), sim in zip(runs, sims, strict=True):
                db = os.path.join(where, f"{mode}-{kind}-{interval:g}-{commit}.sqlite")
                _prepare(mode, db)  # made here: its syncs are not the run's
                trace = db + ".strace"
                argv = [sys.executable, "-m", "pymb.bench.wear", mode, kind, sim.port,
                        str(interval), str(seconds), db,
                        *([] if commit is None else [str(commit)])]
                if opts.quick:  # forked (see pymb.bench.forked), no fdatasync count
                    procs.append((children.start(f"SD wear {mode} {kind}", argv, env=_env(),
                                                 stdin=False), "", commit, seconds))
                    continue
                if strace:
                    argv = [strace, "-f", "-c", "-e", "trace=fsync,fdatasync", "-o", trace,
                            "--", *argv]
                procs.append((subprocess.Popen(argv, stdout=subprocess.PIPE, text=True,
                                               env=_env()), trace, commit, seconds))
            for p, trace, commit, seconds in procs:
                if isinstance(p, subprocess.Popen):
                    out, _ = p.communicate(timeout=seconds + 300)
                else:
                    out = p.readline(seconds + 300)
                    children.stop(p)
                row = json.loads(out.strip().splitlines()[-1])
                row["commit_interval"] = commit
                syncs = _syncs(trace) if strace and trace else None
                n = max(1, row["samples"])
                row.update(written_per_sample=row["written"] / n,
                           stored_per_sample=row["stored"] / n,
                           ratio=row["written"] / max(1, row["stored"]),
                           syncs_per_s=None if syncs is None else syncs / row["elapsed"])
                rows.append(row)
            for s in sims:
                children.stop(s)
    return rows


def _env() -> dict[str, str]:
    from pymb.child import python_env
    return {**python_env(), "PYTHONDONTWRITEBYTECODE": "1"}  # no .pyc counted as written


def table(rows: list[dict[str, Any]]) -> Any:
    """The SD wear rows as a report table."""
    from pymb.bench.table import Table
    from pymb.logger.config import COMMIT_INTERVAL

    def syncs(r: dict[str, Any]) -> str:
        return "-" if r["syncs_per_s"] is None else f"{r['syncs_per_s']:.2f}"

    out = []
    for r in rows:
        what = "hub sweep" if r["kind"] == "hub" else "CoolPro sample"
        when = "wire speed" if r["interval"] == 0 else f"every {r['interval']:g} s"
        who = "pymb log" if r["mode"] == "pymb" else "naive (INSERT + COMMIT each)"
        if r.get("commit_interval") is not None:
            who += f" --commit-interval {r['commit_interval']:g}"
        steady = "-" if r.get("steady") is None else f"{r['steady']:.2f}x"
        bps = "-" if r.get("steady_bps") is None else f"{r['steady_bps'] / 1024:,.1f} KB/s"
        frames = r.get("wal_frames_per_commit")
        out.append([what, when, who, f"{r['elapsed']:,.0f} s", f"{r['samples']:,}",
                    f"{r['stored_per_sample']:,.0f} B",
                    f"{r['written_per_sample']:,.0f} B", f"{r['ratio']:.2f}x", steady, bps,
                    "-" if frames is None else f"{frames:.1f}", syncs(r)])
    return Table(
        "SD wear: bytes written to the disk per sample, beside the bytes stored",
        "each run its own process against its own simulator on a line emulated at 115200; "
        "written: write_bytes of /proc/PID/io (pages dirtied, what writeback sends to the "
        "disk: WAL, database, -shm), the file and schema made before; stored: the bytes in "
        "use on the samples' table and index pages (dbstat); steady: from the first commit "
        "to the end (the start's one-off writes left out, the last checkpoint in), as a "
        "ratio and per second; run: its length, many of pymb's commits (one at the latest "
        f"{COMMIT_INTERVAL:g} s after a read); WAL frames: pages a commit wrote to the WAL "
        "(its frame headers; pymb only); fdatasync: strace -c",
        ["sample", "rate", "logger", "run", "samples", "stored", "written", "written / stored",
         "steady", "steady written/s", "WAL frames / commit", "fdatasync/s"], out,
        [False, False, False, True, True, True, True, True, True, True, True, True], [])


def targets(rows: list[dict[str, Any]]) -> list[tuple[str, str, float | None, str, bool | None]]:
    """The SD wear goals against this run: at wire speed, bytes written over
    bytes stored; at 1 s, bytes written per second (two 4 KB pages)."""
    out: list[tuple[str, str, float | None, str, bool | None]] = []
    for r in rows:
        if r["mode"] != "pymb" or r.get("commit_interval") is not None:
            continue  # the goals are the default's
        kind = "hub sweep" if r["kind"] == "hub" else "CoolPro"
        if r["interval"] == 0:
            value = r.get("steady")
            out.append((f"bytes written / stored, {kind} at wire speed (steady)", "<= 3",
                        value, "x", None if value is None else value <= 3.0))
        else:
            bps = r.get("steady_bps")
            value = None if bps is None else bps / 1024
            out.append((f"KB written per second, {kind} every {r['interval']:g} s (steady)",
                        f"<= {PER_SECOND_GOAL // 1024}", value, "KB/s",
                        None if value is None else value * 1024 <= PER_SECOND_GOAL))
    return out


if __name__ == "__main__":
    sys.exit(main())
