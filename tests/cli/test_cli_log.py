"""``pymb log`` as a real process against simulated devices: faults and
exit codes, backoff, device names, the status line, mistakes in the TOML
file, signals."""

from __future__ import annotations

import fcntl
import os
import re
import signal
import sqlite3
import subprocess
import sys
import termios
from pathlib import Path

import pytest
from clikit import STOP_BOUND, Pty, digest, no_traceback
from conftest import PYMB, PYMB_ENV, run_pymb
from dbwait import count, wait_for

from pymb.extras import install_hint
from pymb.sim import Simulator


def test_log_hub_where_a_coolpro_sits_is_a_fault_not_samples(sim3: Simulator,
                                                             tmp_path: Path) -> None:
    db = tmp_path / "wrong.sqlite"
    r = run_pymb("log", "hub:40", "--port", sim3.port, "--seconds", "3", "--out", str(db))
    no_traceback(r)
    assert r.returncode == 3, r.stderr
    assert "answers like a CoolPro, not a hub" in r.stderr
    assert "delivered no sample" in r.stderr
    final = [ln for ln in r.stderr.splitlines() if " samples " in ln and "faults" in ln][-1]
    assert not re.search(r"faults 0\b", final), final
    assert " ok" not in final, final
    con = sqlite3.connect(db)
    assert con.execute("SELECT COUNT(*) FROM samples").fetchone()[0] == 0
    n = con.execute("SELECT COUNT(*) FROM events WHERE kind = 'no_value'").fetchone()[0]
    # Backed off (0.5 s, 1 s, 2 s...): a handful of faults, not thousands of samples.
    assert 1 <= n <= 5, n
    msg = con.execute("SELECT message FROM events WHERE kind = 'no_value'").fetchone()[0]
    assert "answers like a CoolPro" in msg
    assert "next try in" in msg
    con.close()
    assert db.stat().st_size < 1_000_000


def test_old_firmware_hub_says_how_to_log_it(sim3: Simulator, tmp_path: Path) -> None:
    r = run_pymb("log", "hub:7", "--port", sim3.port, "--seconds", "2", "--out",
                 str(tmp_path / "a.sqlite"))
    assert r.returncode == 3, r.stderr
    assert "hub:7,channels=50" in r.stderr, r.stderr
    # The command line sets what only TOML could: channels (and humidity_unit).
    db = tmp_path / "b.sqlite"
    r = run_pymb("log", "hub:7,channels=50,humidity_unit=1", "--port", sim3.port, "--seconds", "2",
                 "--out", str(db), "--quiet")
    assert r.returncode == 0, r.stderr
    con = sqlite3.connect(db)
    assert con.execute("SELECT MAX(channel) FROM hub").fetchone()[0] == 50
    con.close()


@pytest.mark.ctrl_c
def test_bus_that_never_opens_is_a_fault_and_exit_4(sim3: Simulator, tmp_path: Path) -> None:
    cfg = tmp_path / "two.toml"
    cfg.write_text(f"""
[output]
path = "{tmp_path / 'two.sqlite'}"
[[bus]]
name = "good"
port = "{sim3.port}"
[[bus.device]]
type = "coolpro"
[[bus]]
name = "typo"
port = "/dev/ttyUSB-typo"
[[bus.device]]
type = "hub"
""")
    p = Pty(["log", "--config", str(cfg)], cols=80)
    assert p.read_until(b"faults", 30)
    assert p.read_until(b"/dev/ttyUSB-typo", 30)  # the status line names the failing bus
    took = p.interrupt()
    print(f"log stopped {took:.3f} s after SIGINT")
    assert took < STOP_BOUND
    assert p.proc.returncode == 4
    text = p.out.decode(errors="replace")
    assert "bus typo never opened its port" in text
    assert "no such port" in text
    assert "Traceback" not in text


def test_device_that_never_answers_gives_exit_3_and_is_named(sim3: Simulator,
                                                             tmp_path: Path) -> None:
    r = run_pymb("log", "coolpro:40", "coolpro:41", "--port", sim3.port, "--seconds", "2",
                 "--timeout", "0.1", "--out", str(tmp_path / "x.sqlite"))
    assert r.returncode == 3, r.stderr
    assert "coolpro-41 delivered no sample" in r.stderr
    assert "coolpro-40 delivered" not in r.stderr


def test_a_device_that_keeps_failing_is_backed_off(sim3: Simulator, tmp_path: Path) -> None:
    db = tmp_path / "silent.sqlite"
    r = run_pymb("log", "coolpro:41", "--port", sim3.port, "--timeout", "0.05", "--seconds", "4",
                 "--out", str(db), "--quiet")
    assert r.returncode == 3
    con = sqlite3.connect(db)
    msgs = [m for (m,) in con.execute("SELECT message FROM events WHERE kind = 'timeout' "
                                      "ORDER BY id")]
    con.close()
    # Ten timeouts in a row, then 0.5 s, 1 s, 2 s between tries: not ~40 in 4 s.
    assert 10 <= len(msgs) <= 14, len(msgs)
    assert "next try" not in msgs[8]
    assert msgs[9].endswith("next try in 0.5 s")
    assert msgs[10].endswith("next try in 1 s")


def test_default_names_on_two_buses_are_qualified(tmp_path: Path) -> None:
    from pymb.logger import load_config

    cfg = tmp_path / "two.toml"
    cfg.write_text(TOML_BUS.replace('"coolpro"', '"hub"') +
                   TOML_BUS.replace('"line1"', '"line2"').replace("USB0", "USB1")
                   .replace('"coolpro"', '"hub"'))
    names = [d.name for b in load_config(cfg).buses for d in b.devices]
    assert names == ["line1-hub-1", "line2-hub-1"]


@pytest.mark.ctrl_c
def test_log_status_line_is_one_line_that_fits(tmp_path: Path) -> None:
    p = Pty(["log", "coolpro", "hub", "--port", "/dev/ttyUSB-missing-for-a-long-name-test",
             "--out", str(tmp_path / "s.sqlite")], cols=80)
    assert p.read_until(b"retry", 5) or p.read_until(b"faults 3", 10)
    assert p.read_until(b"faults 3", 20)  # the status line is redrawn every 0.5 s: a few
    p.interrupt()
    # Every redraw starts with \r + erase-line and never wraps: the screen
    # holds one status line, not one per redraw.
    draws = [d for d in p.out.split(b"\r\x1b[K") if d.strip()]
    assert len(draws) >= 3
    for d in draws[:-1]:
        line = d.decode(errors="replace")
        assert "\n" not in line, repr(line)
        assert len(line) <= 79, repr(line)
    screen = [ln for ln in p.screen() if ln.strip()]
    assert sum("samples" in ln for ln in screen) <= 2, screen  # the live one and the final


def test_skipped_interval_slots_are_shown(tmp_path: Path) -> None:
    db = tmp_path / "slots.sqlite"
    with Simulator(["hub:1,delay=0.12"], seed=1) as s:
        r = run_pymb("log", "hub", "--port", s.port, "--interval", "0.05", "--seconds", "2",
                     "--out", str(db))
    assert r.returncode == 0, r.stderr
    m = re.search(r"(\d+) interval slot\(s\) skipped", r.stderr)
    assert m, r.stderr
    assert int(m.group(1)) > 5, r.stderr
    assert re.search(r"skipped \d+", r.stderr)  # in the status line too
    con = sqlite3.connect(db)
    events = [m for (m,) in con.execute("SELECT message FROM events WHERE kind = 'skipped'")]
    con.close()
    assert events
    assert all("poll slot(s) of 0.05 s skipped" in e for e in events)
    assert sum(int(e.split()[0]) for e in events) == int(m.group(1))


def test_log_refuses_to_append_another_format(logged: Path, tmp_path: Path) -> None:
    before = digest(logged)
    r = run_pymb("log", "coolpro", "--port", "/dev/null", "--format", "csv", "--out", str(logged),
                 "--seconds", "1")
    no_traceback(r)
    assert r.returncode == 2
    assert "refusing to append CSV" in r.stderr
    assert digest(logged) == before
    doc = tmp_path / "report.txt"
    doc.write_text("quarterly numbers\n")
    for fmt in ("sqlite", "csv", "jsonl", "influx"):
        r = run_pymb("log", "coolpro", "--port", "/dev/null", "--format", fmt, "--out", str(doc),
                     "--seconds", "1")
        assert r.returncode == 2, (fmt, r.stderr)
        assert "refusing" in r.stderr, (fmt, r.stderr)
        assert len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "report.txt exists and is not InfluxDB line protocol that pymb wrote" in r.stderr
    assert doc.read_text() == "quarterly numbers\n"
    # a wide CSV pymb export wrote: its columns do not take log's long rows
    wide = tmp_path / "wide.csv"
    r = run_pymb("export", str(logged), "--csv", str(wide), "--layout", "wide")
    assert r.returncode == 0, r.stderr
    before = digest(wide)
    r = run_pymb("log", "coolpro", "--port", "/dev/null", "--format", "csv", "--out", str(wide),
                 "--seconds", "1")
    assert r.returncode == 2, r.stderr
    assert r.stderr.strip().splitlines() == [
        f"pymb log: {wide} is a wide CSV (pymb export --layout wide), whose columns the long "
        "rows pymb log writes do not fit: refusing to append to it; choose another --out"]
    assert digest(wide) == before
    # A file pymb wrote in that format is appended to (the port fails: events only).
    for fmt in ("csv", "jsonl", "influx"):
        own = tmp_path / f"own.{fmt}"
        for _ in range(2):
            r = run_pymb("log", "coolpro", "--port", "/dev/ttyUSB-none", "--format", fmt, "--out",
                         str(own), "--seconds", "0.7")
            assert r.returncode == 4, (fmt, r.stderr)
            assert "refusing" not in r.stderr, (fmt, r.stderr)
        assert own.stat().st_size > 0


TOML_BUS = """
[[bus]]
name = "line1"
port = "/dev/ttyUSB0"
[[bus.device]]
type = "coolpro"
"""


@pytest.mark.parametrize(("toml", "message"), [
    ("[outptu]\npath = 'x.sqlite'\n" + TOML_BUS, "unknown section [outptu]; did you mean 'output'"),
    ("[output]\nfile = 'x.sqlite'\n" + TOML_BUS, "unknown key 'file'; did you mean 'path'"),
    ("[output]\npath = 'x.sqlite'\n" + TOML_BUS.replace('type = "coolpro"',
                                                       'type = "coolpro"\nadress = 41'),
     "unknown key 'adress'; did you mean 'address'"),
    (TOML_BUS + TOML_BUS.replace("/dev/ttyUSB0", "/dev/ttyUSB1"), "two buses are named 'line1'"),
    (TOML_BUS + TOML_BUS.replace('"line1"', '"line2"'), "use the same port /dev/ttyUSB0"),
    (TOML_BUS.replace('type = "coolpro"', 'type = "coolpro"\nname = "a"') +
     TOML_BUS.replace('"line1"', '"line2"').replace("USB0", "USB1")
     .replace('type = "coolpro"', 'type = "hub"\nname = "a"'), "two devices are named 'a'"),
    ('[mqtt]\nurl = "broker.lan"\n' + TOML_BUS, "bad.toml: [mqtt]: bad MQTT URL 'broker.lan'"),
    ('[mqtt]\nurl = "mqtt://broker.lan"\nstart = "newest"\n' + TOML_BUS,
     "bad.toml: [mqtt]: MQTT start must be oldest or now"),
])
def test_toml_mistakes_are_named(tmp_path: Path, toml: str, message: str) -> None:
    cfg = tmp_path / "bad.toml"
    cfg.write_text(toml)
    r = run_pymb("log", "--config", str(cfg), "--seconds", "1")
    no_traceback(r)
    assert r.returncode == 2, r.stderr
    assert message in r.stderr, r.stderr
    assert not (tmp_path / "x.sqlite").exists()
    assert not list(Path.cwd().glob("x.sqlite"))


@pytest.mark.parametrize(("toml", "message"), [
    (TOML_BUS + "[output]\nmax_mb = 1e999\n", "c.toml: output: max_mb must be a positive number"),
    (TOML_BUS + "[output]\nmax_mb = nan\n", "max_mb must be a positive number, got nan"),
    (TOML_BUS + "[output]\nmax_age_days = inf\n", "max_age_days must be a positive number"),
    (TOML_BUS + "[output]\nformat = 'parquet'\n", "unknown format 'parquet'; use one of sqlite"),
    (TOML_BUS.replace('name = "line1"', 'name = "line1"\ninterval = nan'),
     "interval must be a number of seconds >= 0, got nan"),
    (TOML_BUS.replace('name = "line1"', 'name = "line1"\ninterval = inf'),
     "interval must be a number of seconds >= 0, got inf"),
    (TOML_BUS.replace('/dev/ttyUSB0"', '/dev/ttyUSB0"\nbaud = "fast"'),
     "c.toml: bus 1: baud has the wrong type ('fast')"),
    (TOML_BUS.replace('/dev/ttyUSB0"', '/dev/ttyUSB0"\nparity = "X"'),
     "c.toml: bus 'line1': parity must be 'N', 'E' or 'O', got 'X'"),
    (TOML_BUS.replace('/dev/ttyUSB0"', '/dev/ttyUSB0"\nbaud = 12345'),
     "c.toml: bus 'line1': baudrate 12345 is not a rate the serial driver supports"),
    (TOML_BUS.replace('port = "/dev/ttyUSB0"', 'tcp = "127.0.0.1:1"\nbaud = 19200'),
     'c.toml: bus 1: baud is for a serial line (port), not tcp = "127.0.0.1:1"'),
    (TOML_BUS.replace('port = "/dev/ttyUSB0"', 'udp = "127.0.0.1:1"\nparity = "E"'),
     'c.toml: bus 1: parity is for a serial line (port), not udp = "127.0.0.1:1"'),
    (TOML_BUS.replace('type = "coolpro"', 'type = "coolpro"\naddress = "40"'),
     "c.toml: bus 1, device 1: address has the wrong type ('40')"),
    (TOML_BUS + "[mqtt]\nurl = 5\n", "c.toml: [mqtt] url has the wrong type (5)"),
    (TOML_BUS + "[output]\nheartbeat_s = 5\n", "heartbeat_s go with on_change = true"),
])
def test_toml_values_out_of_range_are_named_once(tmp_path: Path, toml: str,
                                                 message: str) -> None:
    """Non-finite numbers, an unknown format and wrongly typed values are one
    line naming the file once, never a traceback, and nothing is created."""
    cfg = tmp_path / "c.toml"
    cfg.write_text(toml)
    r = run_pymb("log", "--config", "c.toml", "--seconds", "1", cwd=tmp_path)
    no_traceback(r)
    assert r.returncode == 2, r.stderr
    assert message in r.stderr, r.stderr
    assert "c.toml: c.toml" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.toml"]


def test_a_bad_line_setting_creates_nothing(tmp_path: Path) -> None:
    """A baud rate the serial driver lacks is one line before the output is
    opened: no database is left behind."""
    r = run_pymb("log", "coolpro", "--port", "/dev/ttyUSB-none", "--baud", "12345",
                 "--out", "x.sqlite", "--seconds", "1", cwd=tmp_path)
    no_traceback(r)
    assert r.returncode == 2, r.stderr
    assert "baudrate 12345 is not a rate the serial driver supports" in r.stderr, r.stderr
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("kind", ["dir", "file"])
@pytest.mark.parametrize("toml", [False, True])
def test_a_port_that_can_never_open_is_refused_before_anything(tmp_path: Path, kind: str,
                                                               toml: bool) -> None:
    """A --port (or a bus's port) that is a directory or a regular file is a
    mistake, not an adapter yet to be plugged in: one line, exit 2, no database."""
    port = tmp_path / "port"
    if kind == "dir":
        port.mkdir()
    else:
        port.write_text("not a tty\n")
    what = "a directory" if kind == "dir" else "a regular file"
    if toml:
        (tmp_path / "c.toml").write_text(TOML_BUS.replace("/dev/ttyUSB0", str(port)))
        argv = ["--config", "c.toml"]
        said = f"pymb log: c.toml: bus 'line1': port {port} is {what}, not a serial port\n"
    else:
        argv = ["coolpro", "--port", str(port)]
        said = f"pymb log: --port {port} is {what}, not a serial port\n"
    r = run_pymb("log", *argv, "--out", "x.sqlite", "--seconds", "1", cwd=tmp_path)
    no_traceback(r)
    assert (r.returncode, r.stderr) == (2, said)
    assert not (tmp_path / "x.sqlite").exists()


def test_interval_must_be_finite_on_the_command_line(tmp_path: Path) -> None:
    for bad in ("nan", "inf"):
        r = run_pymb("log", "coolpro", "--port", "/dev/ttyUSB0", "--interval", bad,
                     "--seconds", "1", cwd=tmp_path)
        no_traceback(r)
        assert r.returncode == 2, r.stderr
        assert f"got {bad}" in r.stderr, r.stderr
    assert list(tmp_path.iterdir()) == []


def test_toml_device_without_address_takes_the_default(sim3: Simulator, tmp_path: Path) -> None:
    cfg = tmp_path / "ok.toml"
    db = tmp_path / "ok.sqlite"
    cfg.write_text(f'[output]\npath = "{db}"\n' + TOML_BUS.replace("/dev/ttyUSB0", sim3.port))
    r = run_pymb("log", "--config", str(cfg), "--seconds", "1.5", "--quiet")
    assert r.returncode == 0, r.stderr
    con = sqlite3.connect(db)
    assert con.execute("SELECT name, address FROM devices").fetchall() == [("coolpro-40", 40)]
    con.close()


@pytest.mark.parametrize(("output", "flags", "first"), [
    ('[output]\nformat = "jsonl"\n', [], "{"),
    ('[output]\nformat = "csv"\n', [], "time_utc,time,bus,"),
    ("", ["--format", "csv"], "time_utc,time,bus,"),
    ('[output]\nformat = "sqlite"\n', ["--format", "influx"], "pymb_event,"),
])
def test_toml_without_a_path_writes_a_text_format_to_stdout(
        sim3: Simulator, tmp_path: Path, output: str, flags: list[str], first: str) -> None:
    """A text format (in the file or by --format) with no path in [output] goes to
    stdout, as on the command line: not refused under a SQLite name never written."""
    (tmp_path / "c.toml").write_text(output + TOML_BUS.replace("/dev/ttyUSB0", sim3.port))
    r = run_pymb("log", "--config", "c.toml", *flags, "--seconds", "1", "--quiet",
                 cwd=tmp_path)
    no_traceback(r)
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith(first), r.stdout[:200]
    assert "coolpro-40" in r.stdout
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.toml"]


@pytest.mark.parametrize(("output", "flags"), [
    ("", ["--format", "csv", "--out", "x.csv", "--max-mb", "5"]),
    ("", ["--format", "jsonl", "--out", "x.jsonl", "--max-age-days", "7"]),
    ('[output]\nformat = "influx"\npath = "x.lp"\nmax_mb = 50\n', []),
    ('[output]\npath = "x.csv"\nmax_age_days = 30\n', ["--format", "csv"]),
])
def test_a_size_or_age_limit_on_a_text_format_is_refused(
        sim3: Simulator, tmp_path: Path, output: str, flags: list[str]) -> None:
    """Only a SQLite database is trimmed: a limit given for a text file, which
    would grow past it, is one line before anything is opened."""
    (tmp_path / "c.toml").write_text(output + TOML_BUS.replace("/dev/ttyUSB0", sim3.port))
    r = run_pymb("log", "--config", "c.toml", *flags, "--seconds", "1", "--quiet",
                 cwd=tmp_path)
    no_traceback(r)
    assert r.returncode == 2, r.stderr
    assert "need the SQLite format" in r.stderr, r.stderr
    assert len(r.stderr.splitlines()) == 1, r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.toml"]


def test_toml_without_a_path_logs_to_pymb_sqlite(sim3: Simulator, tmp_path: Path) -> None:
    (tmp_path / "c.toml").write_text(TOML_BUS.replace("/dev/ttyUSB0", sim3.port))
    r = run_pymb("log", "--config", "c.toml", "--seconds", "1", "--quiet", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert count(tmp_path / "pymb.sqlite", "SELECT count(*) FROM samples") > 0


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
@pytest.mark.ctrl_c
def test_log_flushes_what_it_read_on_sigint(sim3: Simulator, tmp_path: Path, sig: int) -> None:
    db = tmp_path / "flush.sqlite"
    p = Pty(["log", "coolpro", "--port", sim3.port, "--out", str(db)])
    assert p.read_until(b"samples", 20)
    assert p.read_more(b"samples", 2, 20)  # two more status lines: it has read more
    took = p.interrupt(sig)
    assert took < STOP_BOUND
    assert p.proc.returncode == 0
    m = re.search(rb"logged ([\d,]+) samples", p.out)
    assert m, p.out
    con = sqlite3.connect(db)
    assert con.execute("SELECT COUNT(*) FROM samples").fetchone()[0] == int(
        m.group(1).replace(b",", b""))
    con.close()


def test_mqtt_without_paho_fails_before_creating_anything(tmp_path: Path) -> None:
    """Without the ``pymb-modbus[mqtt]`` extra, ``log --mqtt`` and ``demo --mqtt`` say how
    to install it, create no database and start no simulator."""
    blocker = tmp_path / "nopaho"
    blocker.mkdir()
    (blocker / "sitecustomize.py").write_text(
        "import sys\nfor m in ('paho', 'paho.mqtt', 'paho.mqtt.client'):\n"
        "    sys.modules[m] = None  # as if pymb-modbus[mqtt] were not installed\n")
    env = dict(PYMB_ENV, PYTHONPATH=f"{blocker}{os.pathsep}{PYMB_ENV['PYTHONPATH']}")
    db = tmp_path / "out.sqlite"
    r = run_pymb("log", "coolpro", "--port", "/dev/ttyUSB0", "--out", str(db), "--seconds", "1",
                 "--mqtt", "mqtt://127.0.0.1", env=env)
    no_traceback(r)
    assert r.returncode == 2, r.stderr
    assert f"{sys.executable} -m pip install 'paho-mqtt" in r.stderr, r.stderr
    assert not db.exists()
    r = run_pymb("demo", "--mqtt", "--out", str(db), env=env)
    no_traceback(r)
    assert r.returncode == 2, r.stderr
    assert r.stderr.strip() == (
        f"pymb demo: --mqtt needs paho-mqtt: {install_hint('mqtt')}"), r.stderr
    assert not db.exists()


@pytest.mark.parametrize("nohup", [False, True])
def test_log_ends_cleanly_on_sighup_unless_nohup(sim3: Simulator, tmp_path: Path,
                                                 nohup: bool) -> None:
    """The terminal closing (SIGHUP) ends ``pymb log`` as SIGTERM does: what was
    read is committed and the summary printed. Under ``nohup`` (SIGHUP
    ignored) it keeps logging until SIGTERM."""
    db = tmp_path / "hup.sqlite"
    # A terminal of its own (a pty as its controlling terminal), as in a shell:
    # without one, SIGHUP is a service's reload (tests/service/test_reload.py).
    master, slave = os.openpty()

    def session() -> None:
        os.setsid()
        fcntl.ioctl(slave, termios.TIOCSCTTY, 0)
        if nohup:
            signal.signal(signal.SIGHUP, signal.SIG_IGN)

    p = subprocess.Popen([*PYMB, "log", "coolpro:40", "--port", sim3.port, "--out", str(db)],
                         env=PYMB_ENV, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                         text=True, preexec_fn=session, pass_fds=(slave,))
    os.close(slave)
    try:
        wait_for(db, "SELECT COUNT(*) FROM samples", at_least=20, proc=p)
        p.send_signal(signal.SIGHUP)
        if nohup:
            with pytest.raises(subprocess.TimeoutExpired):
                p.wait(timeout=1.5)
            p.send_signal(signal.SIGTERM)
        _, err = p.communicate(timeout=30)
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
        os.close(master)
    no_traceback(subprocess.CompletedProcess([], p.returncode, "", err))
    assert p.returncode == 0, (p.returncode, err)
    assert f"logged {count(db, 'SELECT COUNT(*) FROM samples'):,} samples" in err, err


def test_log_help_gives_the_commit_policy_the_logger_and_docs_use() -> None:
    """--commit-interval's help quotes the logger's own constants, which
    docs/cli.md states too."""
    from pymb.logger.config import COMMIT_BYTES, COMMIT_INTERVAL
    done = run_pymb("log", "--help")
    assert done.returncode == 0, done.stderr
    text = " ".join(done.stdout.split())
    assert (f"default {COMMIT_INTERVAL:g}; always when {COMMIT_BYTES // 1024} KB of "
            "registers wait") in text
    docs = " ".join((Path(__file__).parents[2] / "docs" / "cli.md").read_text().split())
    assert (f"commits when {COMMIT_BYTES // 1024} KB of registers wait, and at the latest "
            f"{COMMIT_INTERVAL:g} s after a sample was read") in docs
