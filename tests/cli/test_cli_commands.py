"""The ``pymb`` commands (read, scan, watch, simulate, demo) as real
processes (on real pseudo-terminals where a terminal matters): what the user
sees, the exit codes, Ctrl-C, the one device syntax."""

from __future__ import annotations

import json
import os
import re
import signal
import sqlite3
import subprocess
import time
from pathlib import Path

import pytest
from clikit import STOP_BOUND, Pty, no_traceback
from conftest import PYMB, PYMB_ENV, run_pymb
from peerkit import mbap
from wire_peers import RawTcp, tcp_request

import pymb
from pymb.sim import Simulator, SimulatorProcess


def test_rtu_over_tcp_flag_in_commands_and_toml(tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    import json

    from pymb.cli import main
    from pymb.logger import load_config
    from pymb.sim import Simulator

    with Simulator(["coolpro", "hub:250"], transport="rtu-over-tcp", seed=2) as sim:
        where = f"{sim.host}:{sim.tcp_port}"
        assert main(["read", "hub", "--rtu-over-tcp", where, "--address", "250",
                     "--json"]) == 0
        doc = json.loads(capsys.readouterr().out)
        assert len(doc["values"]["temperature_c"]) == 100
        assert main(["scan", "--rtu-over-tcp", where, "--range", "39-41", "--json"]) == 0
        assert "40" in capsys.readouterr().out
        out = tmp_path / "x.jsonl"
        assert main(["log", "--rtu-over-tcp", where, "--device", "coolpro", "--format", "jsonl",
                     "--out", str(out), "--seconds", "0.5", "--quiet"]) == 0
        assert out.read_text().count("\n") > 0
        toml = tmp_path / "bus.toml"
        toml.write_text(f'[[bus]]\nname = "gw"\nrtu_over_tcp = "{where}"\n'
                        '[[bus.device]]\ntype = "coolpro"\naddress = 40\n')
        cfg = load_config(toml)
        client = cfg.buses[0].client()
        assert isinstance(client, pymb.RtuOverTcpClient)
        with client:
            assert len(client.read_input_registers(0, 8, slave=40)) == 8
    assert main(["read", "coolpro", "--rtu-over-tcp", "nowhere"]) == 2
    assert "HOST:PORT" in capsys.readouterr().err


def test_simulate_takes_the_same_humidity_key(tmp_path: Path) -> None:
    with SimulatorProcess(["hub:9,humidity_unit=1"], quiet=True) as s:
        r = run_pymb("read", "hub:9,humidity_unit=1", "--port", s.endpoint, "--json")
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    values = [v for v in doc["values"]["humidity_pct"] if v is not None]
    assert values
    assert all(v == int(v) for v in values)  # whole percent: the 1 % unit


def test_read_says_what_answered_and_exits_3(sim3: Simulator) -> None:
    r = run_pymb("read", "hub:40", "--port", sim3.port)
    no_traceback(r)
    assert r.returncode == 3
    assert "address 40 answers like a CoolPro, not a hub" in r.stderr
    assert "firmware" not in r.stderr.split("CoolPro, not a hub")[0]  # not blamed on it
    r = run_pymb("read", "coolpro:7", "--port", sim3.port)
    assert r.returncode == 3
    assert "answers like a sensor hub, not a CoolPro" in r.stderr


def _scan_whole_range() -> float:
    """Scan 1..255 with a slow hub at 250 and a CoolPro; the seconds it took."""
    with SimulatorProcess(["coolpro", "hub:250,delay=0.1-0.5", "--baud", "9600",
                           "--seed", "4"], quiet=True) as sim3:
        t0 = time.monotonic()
        r = run_pymb("scan", "--port", sim3.endpoint, "--baud", "9600", "--json", timeout=120)
        took = time.monotonic() - t0
    assert r.returncode == 0, r.stderr
    found = {f["address"]: f["device"] for f in json.loads(r.stdout)["found"]}
    assert found == {40: "coolpro", 250: "hub"}, r.stdout
    print(f"scan of 1..255 took {took:.1f} s")
    return took


def test_scan_whole_range_finds_slow_hub_and_coolpro_no_phantom() -> None:
    _scan_whole_range()


@pytest.mark.timing
def test_scan_of_the_whole_range_takes_under_30_s() -> None:
    assert _scan_whole_range() < 30 * float(os.environ.get("PYMB_TIMING_SLACK", "1.5"))


def test_scan_lists_no_phantom_for_a_reply_naming_another_address() -> None:
    with Simulator(["coolpro"], seed=2) as sim3:
        # The CoolPro's first reply names address 41, with a good CRC.
        sim3.faults.inject("wrong_address", count=1, address=40)
        r = run_pymb("scan", "--port", sim3.port, "--range", "30-50", "--json")
    assert r.returncode == 0, r.stderr
    found = {f["address"]: f["device"] for f in json.loads(r.stdout)["found"]}
    assert found == {40: "coolpro"}, r.stdout
    assert "heard once but silent when asked again: 41" in r.stderr


@pytest.mark.ctrl_c
def test_scan_prints_devices_as_found_and_keeps_them_on_ctrl_c() -> None:
    with Simulator(["coolpro:3", "hub:250"], seed=2) as sim3:
        proc = subprocess.Popen([*PYMB, "scan", "--port", sim3.port, "--timeout", "0.2"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=PYMB_ENV)
        assert proc.stdout is not None
        first = proc.stdout.readline()  # flushed at once, stdout being a pipe
        assert first.split()[:2] == [b"3", b"coolpro"], first
        t0 = time.monotonic()
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
        took = time.monotonic() - t0
    print(f"scan stopped {took:.3f} s after SIGINT")
    assert took < STOP_BOUND
    assert proc.returncode == 130
    assert b"Traceback" not in err
    assert b"interrupted" in err


@pytest.mark.ctrl_c
def test_simulate_link_and_port_refuse_what_is_not_theirs(tmp_path: Path) -> None:
    mine = tmp_path / "important"
    mine.write_text("keep me\n")
    r = run_pymb("simulate", "coolpro", "--link", str(mine))
    no_traceback(r)
    assert r.returncode == 2
    assert "refusing to replace" in r.stderr
    assert mine.read_text() == "keep me\n"
    r = run_pymb("simulate", "coolpro", "--port", str(mine))
    no_traceback(r)
    assert r.returncode == 2
    assert "not a serial port" in r.stderr
    assert mine.read_text() == "keep me\n"
    # A link pymb left behind (to a pseudo-terminal) may be replaced, and goes at the end.
    stale = tmp_path / "ttySIM"
    stale.symlink_to("/dev/pts/9999")
    proc = subprocess.Popen([*PYMB, "simulate", "coolpro", "--link", str(stale)],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, env=PYMB_ENV)
    assert proc.stdout is not None
    assert proc.stdout.readline().decode().strip() == str(stale)
    assert os.readlink(stale).startswith("/dev/pts/")
    assert os.readlink(stale) != "/dev/pts/9999"
    proc.send_signal(signal.SIGINT)
    assert proc.wait(30) == 0
    assert not os.path.lexists(stale)


def test_address_zero_is_rejected(sim3: Simulator) -> None:
    for args in (["read", "hub", "--address", "0"], ["watch", "coolpro", "--address", "0"],
                 ["read", "hub:0"], ["log", "hub:0", "--seconds", "1"]):
        r = run_pymb(*args, "--port", sim3.port)
        no_traceback(r)
        assert r.returncode == 2, (args, r.stderr)
        assert "got 0" in r.stderr, (args, r.stderr)


@pytest.mark.parametrize("args", [
    ["read", "hub:250"], ["read", "hub:250", "--json"], ["export", "DB", "--csv", "-"],
    *(["log", "coolpro", "--format", f, "--out", "-", "--quiet"]
      for f in ("csv", "jsonl", "influx"))])
def test_broken_pipe_into_head_exits_quietly(sim3: Simulator, logged: Path,
                                             args: list[str]) -> None:
    args = [str(logged) if a == "DB" else a for a in args]
    if args[0] in ("read", "log"):
        args += ["--port", sim3.port]
    cmd = " ".join(map(repr, [*PYMB, *args])) + " | head -n 1"
    r = subprocess.run(["bash", "-o", "pipefail", "-c", cmd], capture_output=True, text=True,
                       timeout=60, env=PYMB_ENV)
    assert len(r.stdout.splitlines()) == 1
    # stderr is not a terminal: the logger's events are lines there (its one
    # event here: connected); nothing else, no word about the closed pipe
    said = [line for line in r.stderr.splitlines()
            if not line.startswith("pymb log: bus1 connect: polling 1 device(s)")]
    assert said == [], r.stderr
    assert r.returncode in (0, 141)  # pipefail: pymb's own status, as a Unix tool's
    if args[0] == "log":  # logs until stopped: only the closed pipe ends it
        assert r.returncode == 141


def test_unresolvable_tcp_host_says_so() -> None:
    r = run_pymb("read", "coolpro", "--tcp", "nosuchhost.invalid:502")
    no_traceback(r)
    assert r.returncode == 4
    assert "did not resolve" in r.stderr
    assert "refused" not in r.stderr


@pytest.mark.parametrize("command", [
    ["read", "coolpro:99"], ["watch", "coolpro:99"], ["scan", "--range", "90-99"],
    ["log", "coolpro:99", "--out", "OUT"]])
@pytest.mark.ctrl_c
def test_ctrl_c_ends_within_half_a_second_whatever_the_timeout(sim3: Simulator, tmp_path: Path,
                                                               command: list[str]) -> None:
    command = [str(tmp_path / "stop.sqlite") if a == "OUT" else a for a in command]
    p = Pty([*command, "--port", sim3.port, "--timeout", "5"])
    # Wait until the request is under way (the simulator has seen it).
    deadline = time.monotonic() + 20
    before = sim3.stats.requests
    while sim3.stats.requests == before and time.monotonic() < deadline:
        p.read_until(b"\x00", 0.05)
    assert sim3.stats.requests > before
    took = p.interrupt()
    print(f"{command[0]} stopped {took:.3f} s after SIGINT (timeout 5 s)")
    assert took < STOP_BOUND, p.out
    assert b"Traceback" not in p.out
    if command[0] == "log":
        assert p.proc.returncode == 3  # coolpro-99 never answered
        assert b"coolpro-99 delivered no sample" in p.out


def test_watch_count_counts_attempts(sim3: Simulator) -> None:
    r = run_pymb("watch", "coolpro:99", "--port", sim3.port, "--count", "3", "--timeout", "0.1",
                 timeout=30)
    no_traceback(r)
    assert r.returncode == 3
    assert "faults 3/3" in r.stdout


def test_one_device_syntax_everywhere_with_aliases(sim3: Simulator, tmp_path: Path) -> None:
    a = run_pymb("read", "hub:250", "--port", sim3.port, "--json")
    b = run_pymb("read", "hub", "--address", "250", "--port", sim3.port, "--json")
    assert a.returncode == b.returncode == 0
    assert json.loads(a.stdout)["address"] == json.loads(b.stdout)["address"] == 250
    r = run_pymb("read", "hub:250", "--address", "251", "--port", sim3.port)
    assert r.returncode == 2
    assert "give it once" in r.stderr
    r = run_pymb("read", "hub:250,chanels=50", "--port", sim3.port)
    assert r.returncode == 2
    assert "did you mean 'channels'" in r.stderr
    db = tmp_path / "syntax.sqlite"
    r = run_pymb("log", "coolpro:40", "--device", "hub:250", "--port", sim3.port,
                 "--seconds", "1.5", "--out", str(db), "--quiet")
    assert r.returncode == 0, r.stderr
    con = sqlite3.connect(db)
    assert sorted(con.execute("SELECT name FROM devices")) == [("coolpro-40",), ("hub-250",)]
    con.close()
    r = run_pymb("config", "coolpro:40", "--port", sim3.port)
    assert r.returncode == 0
    assert "CoolPro at 40" in r.stdout


@pytest.mark.ctrl_c
def test_watch_hub_fits_80x24_with_the_status_line_on_screen(sim3: Simulator) -> None:
    p = Pty(["watch", "hub:250", "--port", sim3.port], cols=80, rows=24)
    assert p.read_until(b"reads", 20)
    assert p.read_more(b"\x1b[H", 2, 20)  # two more screens drawn
    screen = p.screen()
    p.interrupt()
    assert screen[0].startswith("hub:250 ")
    assert "reads" in screen[0]
    assert "faults" in screen[0]
    assert screen[1].startswith("temperature_c")
    assert any(ln.startswith("humidity_pct") for ln in screen)
    # No line wrapped: the raw frames never write past column 80 or row 24.
    frames = [f for f in p.out.split(b"\x1b[H") if b"reads" in f]
    assert frames
    for frame in frames:
        lines = frame.decode(errors="replace").replace("\r\n", "\n").split("\x1b[K\n")
        assert len(lines) <= 24
        assert all(len(ln.replace("\x1b[K", "").replace("\x1b[J", "")) < 80 for ln in lines)


@pytest.mark.ctrl_c
def test_watch_block_show_json_identity(sim3: Simulator) -> None:
    p = Pty(["watch", "hub:250", "--port", sim3.port, "--block", "pressure_kpa",
             "--show", "1-20", "--identity"], cols=80, rows=24)
    assert p.read_until(b"pressure_kpa", 20)
    assert p.read_more(b"\x1b[H", 1, 20)  # the next screen begun: the first is whole
    screen = p.screen()
    p.interrupt()
    assert any("sensor hub" in ln and "100 channels" in ln for ln in screen), screen
    assert not any(ln.startswith("temperature_c") for ln in screen)
    rows = [ln for ln in screen if re.match(r"\s*\d+: ", ln)]
    assert [ln.split(":")[0].strip() for ln in rows] == ["1", "11"]
    r = run_pymb("watch", "coolpro", "--port", sim3.port, "--json", "--count", "3", "--identity")
    assert r.returncode == 0, r.stderr
    docs = [json.loads(ln) for ln in r.stdout.splitlines()]
    assert len(docs) == 3
    assert all(20 < d["input_voltage_v"] < 30 for d in docs)
    assert docs[0]["identity"]["serial_number"] == 12345


def test_demo_never_claims_more_than_the_wire_allows(tmp_path: Path) -> None:
    r = run_pymb("demo", "--seconds", "3", "--quiet", "--out", str(tmp_path / "demo.sqlite"))
    assert r.returncode == 0, r.stderr
    shares = [int(x) for x in re.findall(r"the wire allows .*?\((\d+)%\)", r.stdout)]
    assert len(shares) == 2, r.stdout
    assert all(0 < s <= 100 for s in shares), r.stdout


@pytest.mark.parametrize("args", [
    ["demo", "--seconds", "-1"], ["demo", "--seconds", "nan"],
    ["watch", "coolpro", "--port", "/dev/ttyUSB0", "--interval", "inf"],
    ["watch", "coolpro", "--port", "/dev/ttyUSB0", "--interval", "nan"],
])
def test_non_finite_or_negative_durations_are_refused(tmp_path: Path, args: list[str]) -> None:
    out = ["--out", str(tmp_path / "d.sqlite")] if args[0] == "demo" else []
    r = run_pymb(*args, *out)
    no_traceback(r)
    assert r.returncode == 2, r.stderr
    assert "must be" in r.stderr, r.stderr
    assert len(r.stderr.splitlines()) == 1, r.stderr
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(("args", "message"), [
    (["hub:1,firmwar=1.07"], "unknown key 'firmwar'; hub takes firmware=..."),
    (["hub:1,channels=50"], "channel count follows its firmware (firmware=1.07: 50)"),
    (["hub,baud=0"], "bad value for baud: '0'"),
    (["coolpro,gap=-1"], "bad value for gap: '-1' (0..60 seconds before each reply)"),
    (["coolpro,delay=61"], "bad value for delay: '61' (0..60 seconds"),
    (["hub,delay=2-1"], "bad value for delay: '2-1' (0..60 seconds"),
    (["coolpro,hardware=70000"], "bad value for hardware: '70000' (a number 0..65535)"),
    (["coolpro,uptime=-5"], "bad value for uptime: '-5' (0..4294967295 seconds)"),
    (["coolpro", "--fault", "late:0.1,delay=-1"],
     "fault 'late:0.1,delay=-1': delay must be 0 or more seconds, got -1.0"),
    (["hub", "--fault", "sensor,seconds=nan"],
     "fault 'sensor,seconds=nan': seconds must be 0 or more seconds, got nan"),
    (["hub", "--fault", "late,colour=1"], "fault 'late,colour=1': unknown key 'colour'; use "
                                           "channels=..., extra=..., delay=..."),
    (["hub", "--baud", "0"], "baud must be a positive number of bit/s, got 0"),
    (["hub", "--baud", "-5"], "baud must be a positive number of bit/s, got -5"),
])
def test_simulate_mistakes_are_named(args: list[str], message: str) -> None:
    """The simulator's device spec names the wrong key as read/log do, and a
    zero or negative speed is refused instead of serving a line that never
    sends a byte."""
    r = run_pymb("simulate", *args, "--pty", timeout=30)
    no_traceback(r)
    assert r.returncode == 2, r.stderr
    assert message in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr


def test_a_gateways_no_answer_exceptions_are_silence_to_a_scan() -> None:
    # A scripted gateway (not pymb's): unit 3 refuses FC 0x04 with exception 02
    # (a device that is there); every other unit gets 0x0A or 0x0B, the
    # gateway's "no path" and "no answer", which name no device.
    def gateway(_: int, adu: bytes) -> list[tuple[float, bytes]]:
        tid, unit, pdu = tcp_request(adu)
        code = 0x02 if unit == 3 else 0x0A if unit % 2 else 0x0B
        return [(0.0, mbap(tid, unit, bytes((pdu[0] | 0x80, code))))]

    with RawTcp(gateway) as peer:
        r = run_pymb("scan", "--tcp", f"127.0.0.1:{peer.port}", "--range", "1-6",
                     "--timeout", "1", "--json")
    assert r.returncode == 0, r.stderr
    found = json.loads(r.stdout)["found"]
    assert [(d["address"], d["device"]) for d in found] == [(3, "unknown")]
