"""Fixtures of the collector's tests: a real PostgreSQL (Debian's, in a temporary
folder on a free port, stopped by its PID), ``pymb collect`` as a child, and an
independent reading of what a subscriber saw on the broker, to compare the
stored rows with value by value."""

from __future__ import annotations

import json
import math
import signal
import sqlite3
import subprocess
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from conftest import PYMB, PYMB_ENV, wait_until

from pymb.collect.postgres import DATABASE, USER, Postgres, find_postgres

psycopg = pytest.importorskip("psycopg")

#: (node, device, point, time, value, text, state, sample): what a row says
Fact = tuple[str, str, str, float, float | None, str | None, str | None, int | None]


@pytest.fixture(scope="module")
def postgres_cluster() -> Iterator[Postgres]:
    """One PostgreSQL for a test module (its ``initdb`` and start take seconds);
    stopped by its PID at the module's end, its folder removed."""
    if find_postgres() is None:
        pytest.fail("PostgreSQL is not installed: .ci/setup installs it")
    pg = Postgres()
    try:
        yield pg
    finally:
        pg.cleanup()


@pytest.fixture
def postgres(postgres_cluster: Postgres) -> Postgres:
    """The module's PostgreSQL, running, with the database ``pymb`` (its ``url``)
    made anew and empty for this test: nothing a test before stored or left
    connected reaches it."""
    pg = postgres_cluster
    if pg.proc is None:  # first use, or a test stopped it and failed before restarting it
        pg.start()
    with psycopg.connect(f"postgresql://{USER}@127.0.0.1:{pg.port}/postgres",
                         autocommit=True, connect_timeout=30) as con:
        con.execute(f"DROP DATABASE IF EXISTS {DATABASE} WITH (FORCE)")
        con.execute(f"CREATE DATABASE {DATABASE}")
    return pg


class Collectors:
    """``pymb collect`` children, killed at the end of the test if still running."""

    def __init__(self) -> None:
        self.procs: list[subprocess.Popen[str]] = []

    def start(self, broker_url: str, out: str, *more: str) -> subprocess.Popen[str]:
        """``pymb collect --mqtt BROKER --out OUT MORE...``, started."""
        p = subprocess.Popen([*PYMB, "collect", "--mqtt", broker_url, "--out", out, *more],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                             env=PYMB_ENV)
        self.procs.append(p)
        return p

    def close(self) -> None:
        """Kill what still runs."""
        for p in self.procs:
            if p.poll() is None:
                p.kill()
            p.communicate(timeout=30)


@pytest.fixture
def collectors() -> Iterator[Collectors]:
    """A :class:`Collectors`."""
    c = Collectors()
    try:
        yield c
    finally:
        c.close()


def wait_subscribed(proc: subprocess.Popen[str], timeout: float = 30) -> None:
    """Wait until a collector's stderr says it subscribed (it prints one line then)."""
    assert proc.stderr is not None
    line = proc.stderr.readline()
    assert "subscribed to" in line, line + (proc.stderr.read() if proc.poll() is not None
                                            else "")


def stop(proc: subprocess.Popen[str], timeout: float = 60) -> str:
    """SIGTERM; it must end with 0 (after its batch). Returns the rest of stderr."""
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=timeout)
    assert proc.returncode == 0, err
    return err


def _float(v: Any) -> float | None:
    if isinstance(v, bool):
        return float(v)
    if isinstance(v, int | float) and math.isfinite(v):
        return float(v)
    return None


def expected_plain(messages: list[tuple[str, bytes]], prefix: str = "pymb") -> set[Fact]:
    """What the plain messages a subscriber received say, one fact per value,
    read here without pymb's code: ``values`` flattened (a list's item i is
    point ``name_{i+1}``), the state of a null from ``states``."""
    out: set[Fact] = set()
    for topic, payload in messages:
        parts = topic.split("/")
        if len(parts) != 3 or parts[0] != prefix or parts[2] in ("status", "set"):
            continue
        doc = json.loads(payload)
        t = float(doc["time_utc"])
        n = doc.get("sample")
        states = doc.get("states") or {}
        for name, v in doc["values"].items():
            items = list(enumerate(v, 1)) if isinstance(v, list) else [(0, v)]
            for i, x in items:
                point = f"{name}_{i}" if i else name
                st = states.get(name)
                st = st[i - 1] if isinstance(st, list) else st
                if x is None:
                    out.add((parts[1], parts[2], point, t, None, None, st or "no_value", n))
                elif isinstance(x, str):
                    out.add((parts[1], parts[2], point, t, None, x, None, n))
                else:
                    out.add((parts[1], parts[2], point, t, _float(x), None, None, n))
    return out


def sqlite_facts(path: Path) -> list[Fact]:
    """Every row of a collector's SQLite file, as facts (duplicates kept)."""
    con = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    try:
        return [tuple(r) for r in con.execute(  # type: ignore[misc]
            "SELECT node, device, point, time, value, text, state, sample FROM pymb_values")]
    finally:
        con.close()


def sqlite_count(path: Path) -> int:
    """Rows in pymb_values (0 before the table exists)."""
    if not path.exists():
        return 0
    try:
        con = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
        try:
            return int(con.execute("SELECT count(*) FROM pymb_values").fetchone()[0])
        finally:
            con.close()
    except sqlite3.Error:
        return 0


def pg_facts(url: str) -> list[Fact]:
    """Every row of pymb_values in PostgreSQL, as facts (times as Unix seconds)."""
    with psycopg.connect(url) as con:
        return [tuple(r) for r in con.execute(  # type: ignore[misc]
            "SELECT node, device, point, extract(epoch FROM time)::float8, value, text, "
            "state, sample FROM pymb_values")]


def pg_count(url: str) -> int:
    """Rows in pymb_values (0 when it cannot be read now)."""
    try:
        with psycopg.connect(url, connect_timeout=5) as con:
            return int(con.execute("SELECT count(*) FROM pymb_values").fetchone()[0])
    except psycopg.Error:
        return 0


def same_facts(stored: list[Fact], expected: set[Fact], *, us: bool = False) -> None:
    """Every expected fact stored exactly once, nothing else. ``us``: the times
    of PostgreSQL's timestamptz, to the microsecond: facts are matched by their
    sample id instead, and their times must agree within 1 µs."""
    def key(f: Fact) -> tuple[Any, ...]:
        return (*f[:3], *f[4:]) if us else f
    got = [key(f) for f in stored]
    want = {key(f) for f in expected}
    if us:
        times = {key(f): f[3] for f in expected}
        off = [(f, times[key(f)]) for f in stored
               if key(f) in times and abs(f[3] - times[key(f)]) > 1.01e-6]
        assert not off, f"{len(off)} rows at another time, e.g. {off[:2]}"
    assert len(got) == len(set(got)), f"{len(got) - len(set(got))} rows stored twice"
    missing, extra = want - set(got), set(got) - want
    assert not missing, f"{len(missing)} missing, e.g. {sorted(missing)[:3]}"
    assert not extra, f"{len(extra)} unexpected, e.g. {sorted(extra)[:3]}"


def all_received(sub: Any, log_db: Path) -> list[tuple[str, bytes]]:
    """Wait until the subscriber ``sub`` (tests/mqtt_broker.py) has every sample
    of the board's database ``log_db``; what it received."""
    from mqtt_broker import db_ids, plain_ids

    ids = db_ids(log_db)
    sub.wait_until(lambda m: ids <= set(plain_ids(m)), 60,
                   "every logged sample at the subscriber")
    return list(sub.snapshot())


def publish(broker_port: int, messages: list[tuple[str, bytes]], qos: int = 1,
            retain: bool = False) -> None:
    """Publish ``messages`` (at QoS 1: and wait for the broker's
    acknowledgements) from a client of the test's own (``retain``: retained)."""
    import paho.mqtt.client as paho
    from paho.mqtt.enums import CallbackAPIVersion

    c = paho.Client(CallbackAPIVersion.VERSION2, client_id="pymb-test-pub")
    c.connect("127.0.0.1", broker_port)
    c.loop_start()
    try:
        infos = [c.publish(t, p, qos=qos, retain=retain) for t, p in messages]
        for i in infos:
            i.wait_for_publish(30)
    finally:
        c.disconnect()
        c.loop_stop()


def wait_rows(count: Callable[[], int], n: int, what: str, timeout: float = 60) -> None:
    """Wait until ``count()`` reaches ``n``."""
    wait_until(lambda: count() >= n, lambda: f"{what}: {count()} of {n} rows", timeout)
