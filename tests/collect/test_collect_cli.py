"""``pymb collect``'s user mistakes and failures: one line and an exit code
(2 usage, 4 broker or database unreachable at the start, 5 the database
refuses the writes), SIGINT ends with 0, a file that is not SQLite is left
alone, the status line on a terminal."""

from __future__ import annotations

import glob
import json
import os
import pty
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytest.register_assert_rewrite("mqtt_broker", "collectkit")
from collectkit import Collectors, pg_count, psycopg, publish, wait_rows, wait_subscribed  # noqa: E402
from conftest import PYMB, PYMB_ENV, run_pymb  # noqa: E402
from mqtt_broker import Fleet  # noqa: E402

from pymb.collect.postgres import Postgres  # noqa: E402
from pymb.fleet.broker import free_port  # noqa: E402

pytest_plugins = ["mqtt_broker", "collectkit"]


def _one_line(r: subprocess.CompletedProcess[str], code: int, text: str) -> None:
    assert r.returncode == code, r.stderr
    assert "Traceback" not in r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    assert lines[0].startswith("pymb collect: "), r.stderr
    assert text in lines[0], r.stderr


def test_usage_errors_exit_2(tmp_path: Path) -> None:
    out = str(tmp_path / "f.sqlite")
    _one_line(run_pymb("collect", "--mqtt", "http://x", "--out", out), 2, "bad MQTT URL")
    _one_line(run_pymb("collect", "--mqtt", "mqtt://127.0.0.1", "--out", out, "--profile",
                       "sparkplug", "--share", "s"), 2, "--share is for the plain profile")
    _one_line(run_pymb("collect", "--mqtt", "mqtt://127.0.0.1", "--out", out, "--share",
                       "a/b"), 2, "share 'a/b' must be")
    notes = tmp_path / "notes.txt"
    notes.write_text("my notes\n" * 200)
    _one_line(run_pymb("collect", "--mqtt", "mqtt://127.0.0.1", "--out", str(notes)), 2,
              "cannot use")
    assert notes.read_text() == "my notes\n" * 200
    _one_line(run_pymb("collect", "--mqtt", "mqtt://127.0.0.1", "--out",
                       "postgresql://me:secret@[::1/db"), 2, "bad PostgreSQL URL")
    _one_line(run_pymb("collect", "--mqtt", "mqtt://127.0.0.1", "--out",
                       "postgresql://me@127.0.0.1:99999/db"), 2, "the port must be 1..65535")
    r = run_pymb("collect", "--out", out)
    assert r.returncode == 2
    assert "--mqtt" in r.stderr
    # stdout is no database: no SQLite file named '-' is made in the current folder
    _one_line(run_pymb("collect", "--mqtt", "mqtt://127.0.0.1:1", "--out", "-", cwd=tmp_path),
              2, "--out - : the collector stores into a database, not stdout")
    assert not (tmp_path / "-").exists()


def test_nothing_to_reach_at_the_start_exits_4(tmp_path: Path, postgres: Postgres) -> None:
    port = free_port()
    _one_line(run_pymb("collect", "--mqtt", f"mqtt://127.0.0.1:{port}", "--out",
                       str(tmp_path / "f.sqlite")), 4, "cannot reach the broker")
    _one_line(run_pymb("collect", "--mqtt", f"mqtt://127.0.0.1:{port}", "--out",
                       f"postgresql://pymb@127.0.0.1:{port}/pymb"), 4, "cannot connect to")


def test_a_folder_that_does_not_exist_exits_4_and_a_url_of_another_database_2(
        tmp_path: Path) -> None:
    """A SQLite file in a folder not there (a disk not mounted yet) is a
    database that cannot be reached, exit 4, which a service manager
    restarts; nothing is made. A URL of another database is a usage error,
    not a file path to open."""
    broker = f"mqtt://127.0.0.1:{free_port()}"
    out = tmp_path / "disk" / "fleet.sqlite"
    _one_line(run_pymb("collect", "--mqtt", broker, "--out", str(out)), 4,
              f"pymb collect: cannot open {out}: its folder {out.parent} does not exist; "
              "create it, or mount the disk that holds it")
    for url in ("sqlite:///fleet.db", "mysql://me@db/fleet"):
        _one_line(run_pymb("collect", "--mqtt", broker, "--out", url, cwd=tmp_path), 2,
                  f"pymb collect: {url} is a URL pymb collect does not take; --out needs a "
                  "SQLite file or a postgresql:// URL")
    assert list(tmp_path.iterdir()) == []


def test_a_database_locked_by_another_program_at_the_start_exits_4(tmp_path: Path) -> None:
    """Another process holds the collector's SQLite file locked (a rollback
    journal's exclusive lock): after SQLite's wait, one line and exit 4, as
    for a database that cannot be reached; not 2, which a service manager
    does not restart. The file is left as it was."""
    from pymb.collect.sqlstore import SqliteStore
    db = tmp_path / "fleet.sqlite"
    SqliteStore(str(db)).close()
    holder = subprocess.Popen(
        [sys.executable, "-c", (
            "import sqlite3, sys, time\n"
            f"c = sqlite3.connect({str(db)!r}, isolation_level=None)\n"
            "c.execute('PRAGMA journal_mode=DELETE')\n"
            "c.execute('BEGIN EXCLUSIVE')\n"
            "print('locked', flush=True)\n"
            "sys.stdin.read()\n")],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout is not None
        assert holder.stdout.readline() == "locked\n"
        r = run_pymb("collect", "--mqtt", f"mqtt://127.0.0.1:{free_port()}", "--out", str(db),
                     timeout=120)
    finally:
        holder.communicate(timeout=30)
    _one_line(r, 4, f"pymb collect: {db} is locked by another program")


def _dynamic_security() -> str:
    """mosquitto's dynamic security plugin (Debian's mosquitto ships it): unlike an
    acl_file, it refuses a subscription in the SUBACK."""
    found = sorted(glob.glob("/usr/lib/*/mosquitto_dynamic_security.so")
                   + glob.glob("/usr/lib/mosquitto_dynamic_security.so"))
    if not found:
        pytest.fail("mosquitto's dynamic security plugin is missing: .ci/setup installs "
                    "mosquitto")
    return found[0]


def test_a_refused_subscription_exits_4(fleet: Fleet, collectors: Collectors,
                                        tmp_path: Path) -> None:
    deny = [{"acltype": "subscribePattern", "topic": t, "priority": 0, "allow": False}
            for t in ("pymb/#", "$share/+/pymb/#")]
    config = tmp_path / "dynamic-security.json"
    config.write_text(json.dumps({
        "defaultACLAccess": {"publishClientSend": True, "publishClientReceive": True,
                             "subscribe": True, "unsubscribe": True},
        "clients": [], "roles": [{"rolename": "no-pymb", "acls": deny}],
        "groups": [{"groupname": "anonymous", "roles": [{"rolename": "no-pymb"}],
                    "clients": []}],
        "anonymousGroup": "anonymous"}))
    broker = fleet.broker(extra=(f"plugin {_dynamic_security()}",
                                 f"plugin_opt_config_file {config}"))
    out = tmp_path / "f.sqlite"
    for more, topic in (((), "pymb/+/+"), (("--share", "plant"), "$share/plant/pymb/+/+")):
        _one_line(run_pymb("collect", "--mqtt", broker.url, "--out", str(out), *more), 4,
                  f"the broker refused the subscription to {topic}: Not authorized")
    # the same broker takes a subscription the rules allow (the refusal was the topic's)
    wait_subscribed(collectors.start(broker.url, str(out), "--prefix", "other"))


def test_two_collectors_with_one_client_id_are_told_and_back_off(
        fleet: Fleet, collectors: Collectors, tmp_path: Path) -> None:
    """The broker gives a client id's session to the last to connect, so two
    collectors with one ``--client-id`` take it from each other; each says so
    once and reconnects with a growing backoff instead of every second."""
    broker = fleet.broker()
    procs = [collectors.start(broker.url, str(tmp_path / f"c{i}.sqlite"), "--client-id",
                              "twin", "--quiet") for i in (1, 2)]
    said: list[list[str]] = [[], []]
    told = "is another client connected as twin (a second collector with this --client-id)?"
    fds = [p.stderr.fileno() for p in procs if p.stderr is not None]
    rest = [b"", b""]

    def read_for(seconds: float) -> None:
        end = time.monotonic() + seconds
        while (left := end - time.monotonic()) > 0:
            ready, _, _ = select.select(fds, [], [], left)
            for i, fd in enumerate(fds):
                if fd in ready:
                    got = os.read(fd, 65536)  # raw: no line left behind in a buffer
                    assert got, (procs[i].wait(), said[i])  # it ended
                    *lines, rest[i] = (rest[i] + got).split(b"\n")
                    said[i] += [line.decode() for line in lines]
            if told in "".join(said[0] + said[1]) and seconds > 60:
                return

    read_for(61)  # until it is said: 3 short connections in a row, about 5 s
    assert any(told in "".join(s) for s in said), said
    before = [len(s) for s in said]
    read_for(12)  # backing off (2, 4, 8 s...): at most 3 connections each
    again = [sum("again" in line for line in s[n:]) for s, n in zip(said, before, strict=True)]
    assert max(again) <= 3, said
    assert sum(told in line for s in said for line in s) <= 2, said  # once each, at most
    assert all("Traceback" not in line for s in said for line in s)


def test_refused_writes_exit_5_and_sigint_exits_0(
        fleet: Fleet, collectors: Collectors, postgres: Postgres) -> None:
    with psycopg.connect(postgres.url, autocommit=True) as con:
        con.execute("CREATE ROLE writer LOGIN")
        con.execute("GRANT CREATE ON SCHEMA public TO writer")
    url = postgres.url.replace("//pymb@", "//writer@")
    broker = fleet.broker()
    col = collectors.start(broker.url, url, "--client-id", "w1")
    wait_subscribed(col)
    doc = {"time_utc": 1800000000.0, "sample": 1, "values": {"v": 1.0}}
    publish(broker.port, [("pymb/gw/dev", json.dumps(doc).encode())])
    wait_rows(lambda: pg_count(postgres.url), 1, "the first row")
    with psycopg.connect(postgres.url, autocommit=True) as con:
        con.execute("REVOKE INSERT ON pymb_values FROM writer")
    doc["time_utc"] = 1800000001.0
    publish(broker.port, [("pymb/gw/dev", json.dumps(doc).encode())])
    _, err = col.communicate(timeout=60)
    assert col.returncode == 5, err
    assert "Traceback" not in err
    assert "refuses the rows: permission denied" in err.strip().splitlines()[-1], err
    # the refused message was not acknowledged: with the right back, it is stored
    with psycopg.connect(postgres.url, autocommit=True) as con:
        con.execute("GRANT INSERT ON pymb_values TO writer")
    col = collectors.start(broker.url, url, "--client-id", "w1")
    wait_subscribed(col)
    wait_rows(lambda: pg_count(postgres.url), 2, "the refused row, delivered again")
    col.send_signal(signal.SIGINT)
    _, err = col.communicate(timeout=60)
    assert col.returncode == 0, err
    assert "1 rows stored" in err, err


def test_status_line_on_a_terminal(fleet: Fleet, tmp_path: Path) -> None:
    broker = fleet.broker()
    main, child = pty.openpty()
    proc = subprocess.Popen([*PYMB, "collect", "--mqtt", broker.url, "--out",
                             str(tmp_path / "f.sqlite"), "--client-id", "tty"],
                            stdin=child, stdout=child, stderr=child, env=PYMB_ENV)
    os.close(child)
    seen = b""
    try:
        deadline = time.monotonic() + 30
        while b"mqtt ok" not in seen and time.monotonic() < deadline:
            if select.select([main], [], [], 0.5)[0]:
                seen += os.read(main, 4096)
        proc.send_signal(signal.SIGTERM)
        proc.wait(30)
        while select.select([main], [], [], 0.2)[0]:
            try:
                seen += os.read(main, 4096)
            except OSError:
                break
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(30)
        os.close(main)
    text = seen.decode(errors="replace")
    assert proc.returncode == 0, text
    assert "\r\x1b[K0 messages  0/s  0 rows  0/s  lag 0.0 s  bad 0  db ok  mqtt ok" in text, text
    assert "connected to" in text
    assert "0 messages, 0 rows stored" in text
