"""``pymb bench --sections collect``: a fleet's samples into one database.

100 boards' worth of SDM630 samples (the shipped ``eastron-sdm630`` map's 74
points, as ``pymb log --mqtt`` publishes them: plain profile, QoS 1) go
through a local mosquitto to ``pymb collect`` processes writing to SQLite or
to a PostgreSQL of the bench's own (Debian's, in a temporary folder).

* **Throughput**: the collectors are stalled (SIGSTOP) while every sample is
  published, then let go (SIGCONT): values stored per second, from then
  until the last row is committed, and per CPU-second of the collectors
  (their user + system time over the same span).
* **Lag**: the boards publish live (each sample stamped as it goes) at a
  steady rate; the lag of a value is ``received - time`` in the database
  (the commit's clock minus the sample's): its median and p99.
* **Scaling**: two collectors sharing the stream (``--share``) against one.
"""

from __future__ import annotations

import json
import os
import random
import signal
import sqlite3
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from pymb.bench.table import Table
from pymb.extras import install_hint

__all__ = ["run_collect", "tables"]

BOARDS = 100
GOAL_VALUES_PER_S = 100_000  #: into PostgreSQL
GOAL_LAG_P99_S = 2.0
GOAL_SCALING = 1.7  #: two collectors against one


def _points() -> list[str]:
    from pymb.maps import builtin
    return [p.name for p in builtin("eastron-sdm630").points.values() if p.access != "w"]


def _messages(samples: int, t0: float, points: list[str], rng: random.Random,
              period: float = 1.0) -> list[tuple[str, bytes, float]]:
    """(topic, payload, time) of ``samples`` samples of each board, in time order."""
    out = []
    for k in range(samples):
        for b in range(BOARDS):
            t = t0 + k * period + b * period / BOARDS
            doc = {"time_utc": t, "sample": k + 1, "bus": "bus1", "device": "sdm630-1",
                   "type": "map", "address": 1,
                   "values": {p: round(rng.uniform(0, 500), 3) for p in points},
                   "states": {}, "group": None, "unsupported": []}
            out.append((f"pymb/board-{b:03d}/sdm630-1",
                        json.dumps(doc, separators=(",", ":")).encode(), t))
    return out


class _Publisher:
    def __init__(self, port: int) -> None:
        import paho.mqtt.client as mqtt
        from paho.mqtt.enums import CallbackAPIVersion
        self.c = mqtt.Client(CallbackAPIVersion.VERSION2, client_id="pymb-bench-boards")
        self.c.max_inflight_messages_set(1000)
        self.c.max_queued_messages_set(0)
        self.c.connect("127.0.0.1", port)
        self.c.loop_start()

    def send(self, msgs: list[tuple[str, bytes, float]], rate: float | None = None) -> None:
        infos = []
        start = time.monotonic()
        for i, (topic, payload, _t) in enumerate(msgs):
            if rate is not None:
                due = start + i / rate
                if due > time.monotonic():
                    time.sleep(due - time.monotonic())
                doc = json.loads(payload)
                doc["time_utc"] = time.time()
                payload = json.dumps(doc, separators=(",", ":")).encode()
            infos.append(self.c.publish(topic, payload, qos=1))
        for info in infos:
            info.wait_for_publish(60)

    def close(self) -> None:
        self.c.disconnect()
        self.c.loop_stop()


def _cpu(pid: int) -> float:
    """User + system CPU seconds of a process so far."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


class _Target:
    """A database the collectors write to, counted and emptied by the bench."""

    def __init__(self, kind: str, where: str) -> None:
        self.kind, self.where = kind, where

    def count(self) -> int:
        if self.kind == "sqlite":
            if not Path(self.where).exists():
                return 0
            con = sqlite3.connect(self.where, timeout=30)
            try:
                return int(con.execute("SELECT count(*) FROM pymb_values").fetchone()[0])
            except sqlite3.Error:
                return 0
            finally:
                con.close()
        import psycopg
        with psycopg.connect(self.where) as pgc:
            row = pgc.execute("SELECT count(*) FROM pymb_values").fetchone()
            return int(row[0]) if row else 0

    def lags(self) -> list[float]:
        """received - time of every row, seconds."""
        if self.kind == "sqlite":
            con = sqlite3.connect(self.where, timeout=30)
            try:
                return [r[0] for r in con.execute("SELECT received - time FROM pymb_values")]
            finally:
                con.close()
        import psycopg
        with psycopg.connect(self.where) as pgc:
            return [float(r[0]) for r in pgc.execute(
                "SELECT extract(epoch FROM received - time) FROM pymb_values")]

    def empty(self) -> None:
        if self.kind == "sqlite":
            for suffix in ("", "-wal", "-shm"):
                Path(self.where + suffix).unlink(missing_ok=True)
            return
        import psycopg
        with psycopg.connect(self.where) as con:
            con.execute("DROP TABLE IF EXISTS pymb_values CASCADE")


def _start(broker_url: str, target: _Target, cid: str, share: bool) -> subprocess.Popen[str]:
    argv = [sys.executable, "-m", "pymb", "collect", "--mqtt", broker_url, "--out",
            target.where, "--client-id", cid, "--quiet"]
    if share:
        argv += ["--share", "bench"]
    p = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    assert p.stderr is not None
    line = p.stderr.readline()
    if "subscribed to" not in line:
        p.kill()
        raise RuntimeError(f"pymb collect did not start: {line}{p.stderr.read()}")
    return p


def _stop(procs: list[subprocess.Popen[str]]) -> None:
    for p in procs:
        if p.poll() is None:
            os.kill(p.pid, signal.SIGCONT)
            p.send_signal(signal.SIGTERM)
    for p in procs:
        try:
            p.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            p.kill()
            p.communicate(timeout=30)


def _wait_count(target: _Target, n: int, timeout: float) -> float:
    deadline = time.monotonic() + timeout
    while target.count() < n:
        if time.monotonic() > deadline:
            raise RuntimeError(f"{target.kind}: {target.count():,} of {n:,} rows after "
                               f"{timeout:g} s")
        time.sleep(0.1)
    return time.monotonic()


def _throughput(broker: Any, target: _Target, collectors: int, samples: int,
                points: list[str], say: Callable[[str], None]) -> dict[str, Any]:
    target.empty()
    msgs = _messages(samples, time.time() - samples, points, random.Random(collectors))
    values = len(msgs) * len(points)
    say(f"collect: {target.kind}, {collectors} collector(s), {values:,} values")
    procs = [_start(broker.url, target, f"bench-{target.kind}-{collectors}-{i}",
                    collectors > 1) for i in range(collectors)]
    try:
        for p in procs:
            os.kill(p.pid, signal.SIGSTOP)
        pub = _Publisher(broker.port)
        try:
            pub.send(msgs)
        finally:
            pub.close()
        cpu0 = sum(_cpu(p.pid) for p in procs)
        t0 = time.monotonic()
        for p in procs:
            os.kill(p.pid, signal.SIGCONT)
        t1 = _wait_count(target, values, 600)
        cpu = sum(_cpu(p.pid) for p in procs) - cpu0
    finally:
        _stop(procs)
    wall = t1 - t0
    return {"target": target.kind, "collectors": collectors, "values": values,
            "messages": len(msgs), "seconds": wall, "values_per_s": values / wall,
            "values_per_cpu_s": values / cpu if cpu > 0 else None}


def _lag(broker: Any, target: _Target, seconds: float, rate: float, points: list[str],
         say: Callable[[str], None]) -> dict[str, Any]:
    target.empty()
    n = int(seconds * rate)
    msgs = _messages(max(1, n // BOARDS), time.time(), points, random.Random(7))[:n]
    say(f"collect: lag, {target.kind}, {len(msgs):,} samples at {rate:g}/s")
    procs = [_start(broker.url, target, f"bench-lag-{target.kind}", False)]
    try:
        pub = _Publisher(broker.port)
        try:
            pub.send(msgs, rate)
        finally:
            pub.close()
        _wait_count(target, len(msgs) * len(points), 120)
    finally:
        _stop(procs)
    lags = sorted(target.lags())
    return {"target": target.kind, "rate": rate, "samples": len(msgs),
            "lag_p50_s": statistics.median(lags),
            "lag_p99_s": lags[min(len(lags) - 1, int(0.99 * len(lags)))]}


def run_collect(quick: bool, say: Callable[[str], None]) -> dict[str, Any]:
    """The collect section's result (JSON-able), or a skip reason."""
    try:
        import paho.mqtt.client  # noqa: F401
        import psycopg  # noqa: F401
    except ImportError:
        return {"status": "skipped", "reason": f"needs {install_hint('collect')}"}
    from pymb.collect.postgres import Postgres, find_postgres
    from pymb.fleet.broker import Mosquitto, find_mosquitto
    if find_mosquitto() is None or find_postgres() is None:
        return {"status": "skipped", "reason": "needs mosquitto and PostgreSQL installed"}
    samples = 3 if quick else 60
    points = _points()
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="pymb-bench-collect-") as tmp:
        broker = Mosquitto(Path(tmp) / "broker")
        broker.start()
        pg = Postgres()
        try:
            pg.start()
            sqlite = _Target("sqlite", str(Path(tmp) / "fleet.sqlite"))
            postgres = _Target("postgresql", pg.url)
            rows.append(_throughput(broker, sqlite, 1, samples, points, say))
            rows.append(_throughput(broker, postgres, 1, samples, points, say))
            rows.append(_throughput(broker, postgres, 2, samples, points, say))
            lag = _lag(broker, postgres, 1.0 if quick else 10.0, 500.0, points, say)
        finally:
            pg.cleanup()
            broker.stop()
    one, two = rows[1]["values_per_s"], rows[2]["values_per_s"]
    return {"status": "ok", "boards": BOARDS, "points": len(points), "samples": samples,
            "rows": rows, "lag": lag, "scaling": two / one if one else None,
            "cpus": os.cpu_count()}


def tables(section: dict[str, Any]) -> list[Table]:
    """The section's table."""
    if section.get("status") != "ok":
        return [Table("Collect", "", ["status"], [[f"skipped: {section['reason']}"]],
                      [False], [])]
    rows = []
    for r in section["rows"]:
        per_cpu = r["values_per_cpu_s"]
        rows.append([r["target"], str(r["collectors"]), f"{r['values']:,}",
                     f"{r['values_per_s']:,.0f}",
                     "-" if per_cpu is None else f"{per_cpu:,.0f}"])
    lag = section["lag"]
    pg_one = section["rows"][1]["values_per_s"]
    scaling = section["scaling"]
    footer = [
        f"lag ({lag['target']}, {lag['samples']:,} samples published live at "
        f"{lag['rate']:g}/s): median {lag['lag_p50_s']:.3f} s, p99 {lag['lag_p99_s']:.3f} s "
        f"(goal under {GOAL_LAG_P99_S:g} s: "
        f"{'met' if lag['lag_p99_s'] < GOAL_LAG_P99_S else 'NOT met'})",
        f"PostgreSQL, one collector: {pg_one:,.0f} values/s (goal {GOAL_VALUES_PER_S:,}: "
        f"{'met' if pg_one >= GOAL_VALUES_PER_S else 'NOT met'})",
        "two collectors sharing the stream: "
        + ("-" if scaling is None else f"{scaling:.2f}x one (goal {GOAL_SCALING:g}x, "
           f"CPU permitting: {section['cpus']} CPUs also run mosquitto and PostgreSQL)"),
    ]
    return [Table(
        f"Collect: {section['boards']} boards' SDM630 samples ({section['points']} values "
        "each) through mosquitto into one database",
        f"{section['samples']} samples per board published while the collectors are stalled "
        "(SIGSTOP), then drained: values stored per second until the last commit, and per "
        "CPU-second of the collectors",
        ["database", "collectors", "values", "values/s", "values / CPU-s"], rows,
        [False, True, True, True, True], footer)]
