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

from pymb.bench.cpuload import Span
from pymb.bench.table import Table
from pymb.extras import install_hint

__all__ = ["run_collect", "tables"]

BOARDS = 100
GOAL_VALUES_PER_S = 100_000  #: into PostgreSQL
GOAL_LAG_P99_S = 2.0
GOAL_SCALING = 1.7  #: two collectors against one
FLEET_RATE = 100.0  #: samples a second of 100 boards sending one a second


def _points() -> list[str]:
    from pymb.maps import builtin
    return [p.name for p in builtin("eastron-sdm630").points.values() if p.access != "w"]


def _messages(samples: int, t0: float, points: list[str], rng: random.Random,
              period: float = 1.0) -> list[tuple[str, bytes, float]]:
    """(topic, payload, time) of ``samples`` samples of each board, in time order;
    each payload starts with its ``time_utc`` (the live publisher stamps it)."""
    out = []
    for k in range(samples):
        for b in range(BOARDS):
            t = t0 + k * period + b * period / BOARDS
            doc = {"time_utc": t, "sample": k + 1, "bus": "bus1", "device": "sdm630-1",
                   "type": "map", "address": 1,
                   "values": {p: round(rng.uniform(0, 500), 3) for p in points},
                   "states": {p: "value" for p in points}, "group": None,
                   "unsupported": []}
            out.append((f"pymb/board-{b:03d}/sdm630-1",
                        json.dumps(doc, separators=(",", ":")).encode(), t))
    return out


def _stamped(payload: bytes, t: float) -> bytes:
    """The payload with ``time_utc`` set to ``t`` (it is the first member)."""
    rest = payload[payload.index(b",", len(_TIME_KEY)):]
    return _TIME_KEY + repr(t).encode() + rest


_TIME_KEY = b'{"time_utc":'


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
        """Publish at QoS 1 (``rate``: messages a second, each stamped as it
        goes, in bursts every 10 ms) and wait for every PUBACK."""
        infos = []
        start = time.monotonic()
        for i, (topic, payload, _t) in enumerate(msgs):
            if rate is not None:
                due = start + int(i * 100 / rate) / 100
                if due > time.monotonic():
                    time.sleep(due - time.monotonic())
                payload = _stamped(payload, time.time())
            infos.append(self.c.publish(topic, payload, qos=1))
        for info in infos:
            info.wait_for_publish(60)

    def close(self) -> None:
        self.c.disconnect()
        self.c.loop_stop()


class _Target:
    """A database the collectors write to, counted and emptied by the bench
    (through one connection of its own, opened once)."""

    def __init__(self, kind: str, where: str) -> None:
        self.kind, self.where = kind, where
        self._pg: Any = None

    def _query(self, sql: str, args: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
        if self.kind == "sqlite":
            if not Path(self.where).exists():
                return []
            con = sqlite3.connect(self.where, timeout=30)
            try:
                return con.execute(sql.replace("%s", "?"), args).fetchall()
            except sqlite3.OperationalError:  # no table yet
                return []
            finally:
                con.close()
        import psycopg
        if self._pg is None:
            self._pg = psycopg.connect(self.where, autocommit=True)
        try:
            cur = self._pg.execute(sql, args)
        except psycopg.errors.UndefinedTable:
            return []
        return list(cur.fetchall()) if cur.description else []

    def count(self) -> int:
        """Rows stored."""
        r = self._query("SELECT count(*) FROM pymb_values")
        return int(r[0][0]) if r else 0

    def stored(self, point: str) -> int:
        """Messages stored: the rows of one point (every message has each
        point, and its rows are committed together), read through the index
        on (device, point, time), cheaply enough to ask every 50 ms."""
        r = self._query("SELECT count(*) FROM pymb_values WHERE device = %s AND point = %s",
                        ("sdm630-1", point))
        return int(r[0][0]) if r else 0

    def lags(self) -> list[float]:
        """received - time of every row, seconds."""
        if self.kind == "sqlite":
            return [float(r[0]) for r in self._query("SELECT received - time FROM pymb_values")]
        return [float(r[0]) for r in self._query(
            "SELECT extract(epoch FROM received - time) FROM pymb_values")]

    def empty(self) -> None:
        if self.kind == "sqlite":
            for suffix in ("", "-wal", "-shm"):
                Path(self.where + suffix).unlink(missing_ok=True)
            return
        self._query("DROP TABLE IF EXISTS pymb_values CASCADE")

    def close(self) -> None:
        if self._pg is not None:
            self._pg.close()
            self._pg = None


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


def _wait_stored(target: _Target, point: str, messages: int, timeout: float) -> float:
    """Wait until every message is stored; the monotonic time it was seen."""
    deadline = time.monotonic() + timeout
    while (n := target.stored(point)) < messages:
        if time.monotonic() > deadline:
            raise RuntimeError(f"{target.kind}: {n:,} of {messages:,} messages after "
                               f"{timeout:g} s")
        time.sleep(0.05)
    return time.monotonic()


def _throughput(env: _Env, target: _Target, collectors: int, samples: int,
                points: list[str], say: Callable[[str], None]) -> dict[str, Any]:
    target.empty()
    msgs = _messages(samples, time.time() - samples, points, random.Random(collectors))
    values = len(msgs) * len(points)
    say(f"collect: {target.kind}, {collectors} collector(s), {values:,} values")
    procs = [_start(env.broker.url, target, f"bench-{target.kind}-{collectors}-{i}",
                    collectors > 1) for i in range(collectors)]
    try:
        for p in procs:
            os.kill(p.pid, signal.SIGSTOP)
        pub = _Publisher(env.broker.port)
        try:
            pub.send(msgs)
        finally:
            pub.close()
        span = Span({"collectors": ([p.pid for p in procs], False),
                     "broker": ([env.broker.pid or 0], False),
                     "database": ([env.pg.pid or 0] if target.kind == "postgresql" else [],
                                  True)})
        span.start()
        for p in procs:
            os.kill(p.pid, signal.SIGCONT)
        _wait_stored(target, points[-1], len(msgs), 600)
        span.stop()
    finally:
        _stop(procs)
    stored = target.count()
    if stored != values:
        raise RuntimeError(f"{target.kind}: {stored:,} rows stored of {values:,}")
    cpu = span.cpu
    return {"target": target.kind, "collectors": collectors, "values": values,
            "messages": len(msgs), "seconds": span.seconds,
            "values_per_s": values / span.seconds,
            "values_per_cpu_s": values / cpu["collectors"] if cpu["collectors"] > 0 else None,
            "cpu_us_per_value": {k: v / values * 1e6 for k, v in cpu.items()},
            "busy_cores": span.busy_cores,
            "ours_cores": sum(cpu.values()) / span.seconds}


def _lag(env: _Env, target: _Target, seconds: float, rate: float, points: list[str],
         say: Callable[[str], None]) -> dict[str, Any]:
    target.empty()
    n = int(seconds * rate)
    msgs = _messages(max(1, -(-n // BOARDS)), time.time(), points, random.Random(7))[:n]
    say(f"collect: lag, {target.kind}, {len(msgs):,} samples at {rate:g}/s")
    procs = [_start(env.broker.url, target, f"bench-lag-{target.kind}", False)]
    try:
        pub = _Publisher(env.broker.port)
        try:
            pub.send(msgs, rate)
        finally:
            pub.close()
        _wait_stored(target, points[-1], len(msgs), 300)
    finally:
        _stop(procs)
    lags = sorted(target.lags())
    return {"target": target.kind, "rate": rate, "samples": len(msgs),
            "values_per_s": rate * len(points),
            "lag_p50_s": statistics.median(lags),
            "lag_p99_s": lags[min(len(lags) - 1, int(0.99 * len(lags)))]}


class _Env:
    """The broker and the PostgreSQL server of the section."""

    def __init__(self, broker: Any, pg: Any) -> None:
        self.broker, self.pg = broker, pg


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
        # mosquitto's own autosave interval (the fixture's 1 s rewrote every queued
        # message to disk each second while the collectors were stalled)
        broker = Mosquitto(Path(tmp) / "broker", extra=("autosave_interval 1800",))
        broker.start()
        pg = Postgres()
        env = _Env(broker, pg)
        sqlite = _Target("sqlite", str(Path(tmp) / "fleet.sqlite"))
        postgres = _Target("postgresql", pg.url)
        try:
            pg.start()
            rows.append(_throughput(env, sqlite, 1, samples, points, say))
            rows.append(_throughput(env, postgres, 1, samples, points, say))
            rows.append(_throughput(env, postgres, 2, samples, points, say))
            lag = _lag(env, postgres, 1.0 if quick else 10.0,
                       GOAL_VALUES_PER_S / len(points), points, say)
            fleet = _lag(env, postgres, 1.0 if quick else 10.0, FLEET_RATE, points, say)
        finally:
            postgres.close()
            pg.cleanup()
            broker.stop()
    one, two = rows[1]["values_per_s"], rows[2]["values_per_s"]
    return {"status": "ok", "boards": BOARDS, "points": len(points), "samples": samples,
            "rows": rows, "lag": lag, "fleet_lag": fleet, "scaling": two / one if one else None,
            "cpus": os.cpu_count()}


def _capacity(r: dict[str, Any], cpus: int) -> float:
    """Values a second the machine's cores would store at this run's CPU cost
    per value (collectors, broker and database), with nothing else running."""
    us = sum(r["cpu_us_per_value"].values())
    return cpus / us * 1e6 if us > 0 else 0.0


def tables(section: dict[str, Any]) -> list[Table]:
    """The section's table."""
    if section.get("status") != "ok":
        return [Table("Collect", "", ["status"], [[f"skipped: {section['reason']}"]],
                      [False], [])]
    cpus = section["cpus"] or 1
    rows = []
    for r in section["rows"]:
        per_cpu = r["values_per_cpu_s"]
        us = r["cpu_us_per_value"]
        rows.append([r["target"], str(r["collectors"]), f"{r['values']:,}",
                     f"{r['values_per_s']:,.0f}",
                     "-" if per_cpu is None else f"{per_cpu:,.0f}",
                     f"{us['collectors']:.2f}", f"{us['broker']:.2f}",
                     f"{us['database']:.2f}" if r["target"] == "postgresql" else "-",
                     f"{r['busy_cores']:.2f} ({r['ours_cores']:.2f})",
                     f"{_capacity(r, cpus):,.0f}"])
    lag = section["lag"]
    pg_one, pg_two = section["rows"][1], section["rows"][2]
    scaling = section["scaling"]
    footer = [
        f"lag ({lag['target']}, {lag['samples']:,} samples published live at "
        f"{lag['rate']:,.0f}/s, {lag['values_per_s']:,.0f} values/s): median "
        f"{lag['lag_p50_s']:.3f} s, p99 {lag['lag_p99_s']:.3f} s (goal under "
        f"{GOAL_LAG_P99_S:g} s: {'met' if lag['lag_p99_s'] < GOAL_LAG_P99_S else 'NOT met'})",
    ]
    fleet = section.get("fleet_lag")
    if fleet:
        footer.append(
            f"lag of a fleet of 100 boards sending a sample a second ({fleet['samples']:,} "
            f"samples at {fleet['rate']:,.0f}/s, {fleet['values_per_s']:,.0f} values/s): "
            f"median {fleet['lag_p50_s']:.3f} s, p99 {fleet['lag_p99_s']:.3f} s")
    footer += [
        f"PostgreSQL, one collector: {pg_one['values_per_s']:,.0f} values/s (goal "
        f"{GOAL_VALUES_PER_S:,}: "
        f"{'met' if pg_one['values_per_s'] >= GOAL_VALUES_PER_S else 'NOT met'})",
        "two collectors sharing the stream: "
        + ("-" if scaling is None else f"{scaling:.2f}x one (goal {GOAL_SCALING:g}x, CPU "
           f"permitting: with one collector {pg_one['busy_cores']:.2f} of the {cpus} cores "
           f"were busy, {pg_one['ours_cores']:.2f} of them with the collector, broker and "
           f"database; with two {pg_two['busy_cores']:.2f} and {pg_two['ours_cores']:.2f})"),
    ]
    return [Table(
        f"Collect: {section['boards']} boards' SDM630 samples ({section['points']} values "
        "each) through mosquitto into one database",
        f"{section['samples']} samples per board published while the collectors are stalled "
        "(SIGSTOP), then drained: values stored per second until the last commit, per "
        "CPU-second of the collectors, and the CPU microseconds per value of the collectors, "
        "the broker and PostgreSQL; cores busy on the whole machine (with the section's "
        "processes); capacity: the values a second all the machine's cores would store at "
        "that cost",
        ["database", "collectors", "values", "values/s", "values / CPU-s",
         "µs collectors", "µs broker", "µs database", "cores busy (ours)", "capacity"], rows,
        [False, True, True, True, True, True, True, True, True, True], footer)]
