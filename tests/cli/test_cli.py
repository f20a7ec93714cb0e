"""The ``pymb`` command end to end, against the simulators on real ptys:
read, log (rows and events in the database), export, scan, config with reset,
the logger surviving faults and an unplugged port, SIGKILL mid-run."""

from __future__ import annotations

import csv
import itertools
import json
import os
import signal
import sqlite3
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import PYMB, PYMB_ENV, ROOT, run_pymb
from dbwait import count, wait_for
from eventlines import without_events

from pymb.cli import main
from pymb.sim import Simulator


@pytest.fixture
def live_sim() -> Iterator[Simulator]:
    with Simulator(["coolpro", "hub:250"], seed=3) as s:
        yield s


def test_read_coolpro_table_and_json(live_sim: Simulator,
                                     capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["read", "coolpro", "--port", live_sim.port, "--identity"]) == 0
    out = capsys.readouterr().out
    assert "Input Voltage" in out
    assert " V" in out
    assert "Firmware" in out
    assert main(["read", "coolpro", "--port", live_sim.port, "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert 20 < doc["input_voltage_v"] < 30
    assert isinstance(doc["uptime_s"], int)
    assert isinstance(doc["status"], int)


def test_read_hub_shows_states(live_sim: Simulator, capsys: pytest.CaptureFixture[str]) -> None:
    hub = live_sim.device(250)
    hub.set_offline(3)  # type: ignore[attr-defined]
    assert main(["read", "hub", "--port", live_sim.port, "--address", "250"]) == 0
    out = capsys.readouterr().out
    lines = out.splitlines()
    assert lines[0].split()[0] == "ch"
    assert len(lines) >= 101
    assert "offline" in lines[3]  # channel 3
    assert main(["read", "hub", "--port", live_sim.port, "--address", "250", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["states"]["temperature_c"][2] == "offline"
    assert doc["values"]["temperature_c"][2] is None
    assert len(doc["values"]["humidity_pct"]) == 100


def test_user_mistakes_are_messages_with_exit_codes(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["read", "coolpro", "--port", "/dev/ttyUSB-missing"]) == 4
    err = capsys.readouterr().err
    assert "/dev/ttyUSB-missing" in err
    assert "no such port" in err
    assert "Traceback" not in err
    assert main(["read", "coolpro", "--port", "/dev/null", "--address", "300"]) == 2
    assert "address" in capsys.readouterr().err
    r = run_pymb("read", "coolpro", "--port", "/dev/ttyUSB-missing")
    assert r.returncode == 4
    assert "Traceback" not in r.stderr
    assert "no such port" in r.stderr


def test_permission_denied_says_how_to_fix(tmp_path: Path) -> None:
    if os.geteuid() == 0:
        # root ignores file modes: run the check as an unprivileged user.
        nobody = subprocess.run(["id", "-u", "nobody"], capture_output=True, text=True)
        if nobody.returncode != 0:
            pytest.skip("no unprivileged user to run as")
        tty = tmp_path / "ttyS-locked"
        tty.write_text("")
        tty.chmod(0o600)
        tmp_path.chmod(0o755)
        code = (f"import sys; sys.path.insert(0, {str(ROOT)!r}); from pymb.cli import main; "
                f"sys.exit(main(['read', 'coolpro', '--port', {str(tty)!r}]))")
        r = subprocess.run(["setpriv", f"--reuid={nobody.stdout.strip()}", "--regid=65534",
                            "--clear-groups", sys.executable, "-c", code],
                           capture_output=True, text=True, timeout=60)
        if "setpriv" in r.stderr and r.returncode != 4:
            pytest.skip(f"cannot drop privileges here: {r.stderr.strip()}")
        assert r.returncode == 4, r.stderr
        assert "dialout" in r.stderr
        assert "permission denied" in r.stderr


def test_log_then_export(live_sim: Simulator, tmp_path: Path) -> None:
    db = tmp_path / "run.sqlite"
    r = run_pymb("log", "--port", live_sim.port, "--device", "coolpro:40", "--device", "hub:250",
                 "--seconds", "2", "--out", str(db), "--timeout", "0.5")
    assert r.returncode == 0, r.stderr
    assert "logged" in r.stderr
    con = sqlite3.connect(db)
    assert con.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    n_cp = con.execute("SELECT COUNT(*) FROM coolpro_readings").fetchone()[0]
    n_hub = con.execute("SELECT COUNT(DISTINCT sample_id) FROM hub_readings").fetchone()[0]
    assert n_cp > 10
    assert n_hub > 2
    # Raw registers are kept losslessly beside the decoded values.
    blob, v = con.execute(
        "SELECT s.registers, c.input_voltage_v FROM samples s JOIN coolpro c "
        "ON c.sample_id = s.id LIMIT 1").fetchone()
    assert len(blob) == 16
    assert int.from_bytes(blob[:2], "big") / 1000 == v
    rows = con.execute("SELECT COUNT(*) FROM hub WHERE sample_id = "
                       "(SELECT MIN(sample_id) FROM hub)").fetchone()[0]
    assert rows == 100
    assert con.execute("SELECT COUNT(*) FROM events WHERE kind = 'connect'").fetchone()[0] == 1
    con.close()

    out = tmp_path / "out.csv"
    assert main(["export", str(db), "--csv", str(out), "--device", "coolpro-40"]) == 0
    with out.open() as f:
        got = list(csv.DictReader(f))
    assert len(got) == n_cp * 7
    assert {r["quantity"] for r in got} >= {"input_voltage_v", "status", "uptime_s"}


def test_log_to_jsonl_on_stdout(live_sim: Simulator) -> None:
    r = run_pymb("log", "--port", live_sim.port, "--device", "coolpro", "--format", "jsonl",
                 "--out", "-", "--seconds", "1", "--quiet")
    assert r.returncode == 0, r.stderr
    lines = [json.loads(line) for line in r.stdout.splitlines()]
    samples = [x for x in lines if "values" in x]
    assert len(samples) > 5
    assert samples[0]["device"] == "coolpro-40"
    assert without_events(r.stderr) == []  # stderr is not a terminal: only event lines


def test_log_records_faults_and_keeps_going(tmp_path: Path) -> None:
    db = tmp_path / "faults.sqlite"
    with Simulator(["coolpro", "hub"], seed=5) as live_sim:
        live_sim.faults.inject("no_reply", count=2, address=40)
        live_sim.faults.inject("bad_crc", count=1, address=40)
        live_sim.faults.inject("exception", count=1, address=1, code=2)
        r = run_pymb("log", "--port", live_sim.port, "--device", "coolpro", "--device", "hub",
                     "--seconds", "3", "--out", str(db), "--timeout", "0.2")
    assert r.returncode == 0, r.stderr
    con = sqlite3.connect(db)
    kinds = dict(con.execute("SELECT kind, COUNT(*) FROM events GROUP BY kind").fetchall())
    assert kinds.get("timeout", 0) >= 2
    assert kinds.get("protocol", 0) >= 1
    msgs = [m for (m,) in con.execute("SELECT message FROM events WHERE kind = 'protocol'")]
    assert any("CRC" in m for m in msgs)
    assert con.execute("SELECT COUNT(*) FROM coolpro").fetchone()[0] > 5
    con.close()


@pytest.mark.ctrl_c
def test_unplugged_bus_reconnects_while_the_other_keeps_logging(tmp_path: Path) -> None:
    cfg = tmp_path / "two.toml"
    db = tmp_path / "two.sqlite"
    with Simulator(["coolpro"], seed=1) as a, Simulator(["hub"], seed=2) as b:
        cfg.write_text(f"""
[output]
path = "{db}"

[[bus]]
name = "a"
port = "{a.port}"
timeout = 0.3
[[bus.device]]
type = "coolpro"
address = 40

[[bus]]
name = "b"
port = "{b.port}"
timeout = 0.5
[[bus.device]]
type = "hub"
address = 1
""")
        proc = subprocess.Popen([*PYMB, "log", "--config", str(cfg),
                                 "--quiet"], env=PYMB_ENV,
                                stderr=subprocess.PIPE, text=True)
        try:
            # Events, not fixed times: both buses log, a is unplugged and seen
            # so, b goes on logging, a is replugged and logs again.
            per_bus = ("SELECT COUNT(*) FROM samples s JOIN devices d ON d.id = s.device_id "
                       "WHERE d.bus = ?")
            event = "SELECT COUNT(*) FROM events WHERE kind = ? AND bus = 'a'"
            wait_for(db, per_bus, ("a",), proc=proc)
            wait_for(db, per_bus, ("b",), proc=proc)
            a.unplug()
            wait_for(db, event, ("connection",), proc=proc)
            wait_for(db, per_bus, ("b",), at_least=count(db, per_bus, ("b",)) + 4, proc=proc)
            a.replug()
            wait_for(db, event, ("reconnect",), proc=proc)
            wait_for(db, per_bus, ("a",), at_least=count(db, per_bus, ("a",)) + 4, proc=proc)
        finally:
            proc.send_signal(signal.SIGINT)
            _, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    con = sqlite3.connect(db)
    ev = con.execute("SELECT kind, bus, message FROM events ORDER BY id").fetchall()
    assert any(k == "connection" and bus == "a" for k, bus, _ in ev), ev
    assert any(k == "reconnect" and bus == "a" for k, bus, _ in ev), ev
    # Bus b kept logging while bus a was unplugged.
    t_unplug = con.execute("SELECT MIN(time_utc) FROM events WHERE kind = 'connection' "
                           "AND bus = 'a'").fetchone()[0]
    t_back = con.execute("SELECT MIN(time_utc) FROM events WHERE kind = 'reconnect' "
                         "AND bus = 'a'").fetchone()[0]
    during = con.execute("SELECT COUNT(*) FROM samples s JOIN devices d ON d.id = s.device_id "
                         "WHERE d.bus = 'b' AND s.time_utc BETWEEN ? AND ?",
                         (t_unplug, t_back)).fetchone()[0]
    assert during > 3
    after = con.execute("SELECT COUNT(*) FROM samples s JOIN devices d ON d.id = s.device_id "
                        "WHERE d.bus = 'a' AND s.time_utc > ?", (t_back,)).fetchone()[0]
    assert after > 3  # logging resumed on the replugged bus
    con.close()


def test_sigkill_loses_at_most_one_batch(tmp_path: Path) -> None:
    db = tmp_path / "kill.sqlite"
    with Simulator(["coolpro", "hub"], seed=9) as live_sim:
        proc = subprocess.Popen(
            [*PYMB, "log", "--port", live_sim.port, "--device", "coolpro",
             "--device", "hub", "--out", str(db), "--quiet"],
            env=PYMB_ENV)
        try:
            committed = wait_for(db, "SELECT COUNT(*) FROM samples", at_least=20, proc=proc)
        finally:
            proc.kill()
            proc.wait(10)
    con = sqlite3.connect(db)
    assert con.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    assert con.execute("SELECT COUNT(*) FROM samples").fetchone()[0] >= committed
    con.close()


def test_scan_finds_both_devices(live_sim: Simulator, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["scan", "--port", live_sim.port, "--range", "1-3,40,249-250", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    found = {f["address"]: f["device"] for f in doc["found"]}
    assert found == {40: "coolpro", 250: "hub"}


def test_config_changes_address_with_reset_and_verifies(
        capsys: pytest.CaptureFixture[str]) -> None:
    with Simulator(["coolpro"], seed=4) as live_sim:
        assert main(["config", "coolpro", "--port", live_sim.port, "--set-address", "42",
                     "--yes"]) == 0
        out = capsys.readouterr().out
        assert "take effect after a reset" in out
        assert live_sim.device(40).address == 40  # not yet
        assert main(["config", "coolpro", "--port", live_sim.port, "--reset", "--yes"]) == 0
        out = capsys.readouterr().out
        assert "verified" in out
        assert "address 42" in out
        assert main(["read", "coolpro", "--port", live_sim.port, "--address", "42", "--json"]) == 0
        assert json.loads(capsys.readouterr().out)["uptime_s"] < 10


def test_config_refuses_without_confirmation(live_sim: Simulator,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    r = run_pymb("config", "coolpro", "--port", live_sim.port, "--set-address", "41",
                 stdin=subprocess.DEVNULL)
    assert r.returncode == 2
    assert "--yes" in r.stderr
    assert main(["config", "coolpro", "--port", live_sim.port, "--set-address", "300",
                 "--yes"]) == 2
    assert "1..247" in capsys.readouterr().err


def test_demo_runs(tmp_path: Path) -> None:
    db = tmp_path / "demo.sqlite"
    r = run_pymb("demo", "--seconds", "3", "--out", str(db))
    assert r.returncode == 0, r.stderr
    assert "the wire allows" in r.stdout
    assert str(db) in r.stdout
    con = sqlite3.connect(db)
    assert con.execute("SELECT COUNT(*) FROM coolpro").fetchone()[0] > 50
    assert con.execute("SELECT COUNT(DISTINCT sample_id) FROM hub").fetchone()[0] >= 5
    con.close()
    # the finished demo leaves its database and nothing else (no full-disk reserve)
    left = {p.name for p in tmp_path.iterdir()} - {"demo.sqlite", "demo.sqlite-wal",
                                                    "demo.sqlite-shm"}
    assert left == set()


def test_help_lists_every_command() -> None:
    r = run_pymb("--help")
    for cmd in ("demo", "read", "watch", "log", "export", "scan", "config", "simulate"):
        assert cmd in r.stdout


def test_watch_shows_the_rate(live_sim: Simulator, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["watch", "coolpro", "--port", live_sim.port, "--count", "3"]) == 0
    out = capsys.readouterr().out
    assert "3 reads" in out
    assert "/s" in out
    assert "Input Voltage" in out


def test_read_through_a_tcp_gateway(capsys: pytest.CaptureFixture[str]) -> None:
    with Simulator(["coolpro", "hub:250"], transport="tcp", seed=2) as tcp_sim:
        assert main(["read", "hub", "--tcp", f"{tcp_sim.host}:{tcp_sim.tcp_port}",
                     "--address", "250", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert len(doc["values"]["temperature_c"]) == 100


def test_log_csv_and_interval_schedule(live_sim: Simulator, tmp_path: Path) -> None:
    out = tmp_path / "x.csv"
    r = run_pymb("log", "--port", live_sim.port, "--device", "coolpro", "--format", "csv", "--out",
                 str(out), "--interval", "0.25", "--seconds", "2.1", "--quiet")
    assert r.returncode == 0, r.stderr
    with out.open() as f:
        rows = list(csv.DictReader(f))
    times = sorted({float(x["time_utc"]) for x in rows if x["quantity"] == "input_voltage_v"})
    # Slots at 0, 0.25, ... 2.0 s: 8 or 9 polls, none crammed together.
    assert 7 <= len(times) <= 9, times
    gaps = [b - a for a, b in itertools.pairwise(times)]
    assert min(gaps) > 0.15
