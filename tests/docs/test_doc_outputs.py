"""Output shown in the docs is what pymb prints: each example is turned into
a pattern (numbers, times and sizes match any number; ``…`` and ``...`` any
text) and real output of the same command, run against simulated devices or
a scripted responder, must match it line by line. And the examples that
drive pymb from other programs run: the storage page's query on a database
``pymb log`` wrote, Telegraf's ``inputs.execd`` command line."""

from __future__ import annotations

import os
import re
import shlex
import sqlite3
import subprocess
import sys
import tomllib
from pathlib import Path

from conftest import PYMB_ENV, run_pymb
from docblocks import NUMBER, ROOT, assert_shaped, claim_one, shape
from peers import PtyPeer

import pymb
from pymb.cli import build_parser
from pymb.devices import CoolPro
from pymb.sim import Simulator


def test_the_demo_summary_is_what_pymb_demo_prints(tmp_path: Path) -> None:
    block = claim_one("docs/cli.md", "text", how="compare", contains="pymb demo:")
    env = dict(PYMB_ENV, TMPDIR=str(tmp_path))  # its database goes to the temporary folder
    r = subprocess.run([sys.executable, "-m", "pymb", "demo", "--seconds", "2", "--quiet"],
                       env=env, capture_output=True, text=True, timeout=120, check=False)
    assert r.returncode == 0, r.stderr
    text = re.sub(r" \\\n\s+", " ", r.stdout)  # the sqlite3 line, joined as the doc shows it
    real = [line for line in text.splitlines() if line.strip()]
    # the fault counts by kind only when there are faults; the doc's run had two
    real = [re.sub(r"(faults seen: )0$", r"\g<1>2 (1 timeout, 1 protocol)", line)
            for line in real]
    assert_shaped(block, [line.replace(str(tmp_path), "/tmp") for line in real])


def test_the_influx_lines_are_what_pymb_log_writes() -> None:
    block = claim_one("docs/fleet.md", "text", how="compare", contains="pymb_coolpro,")
    with Simulator(["coolpro", "hub:250"], seed=2) as sim:
        r = run_pymb("log", "coolpro:40", "hub:250", "--port", sim.port, "--format", "influx",
                     "--out", "-", "--seconds", "0.5", "--quiet")
    assert r.returncode == 0, r.stderr
    real = r.stdout.splitlines()
    for doc in block.lines():
        # the doc's hub line is channel 7 with a temperature and no humidity
        # sensor: any channel of that shape will do
        pattern = shape(doc).replace("channel=" + NUMBER, "channel=" + NUMBER)
        assert any(re.fullmatch(pattern, line) for line in real), \
            f"{block.where}: no line pymb writes looks like\n  {doc}"


def test_the_telegraf_example_runs_a_pymb_command() -> None:
    block = claim_one("docs/fleet.md", "toml", how="load", contains="[[inputs.execd]]")
    (execd,) = tomllib.loads(block.text)["inputs"]["execd"]
    argv = execd["command"]
    assert argv[0] == "pymb"
    args = build_parser(argv[1]).parse_args(argv[1:])
    assert (args.format, args.out, args.quiet) == ("influx", "-", True)
    assert execd["data_format"] == "influx"


def test_the_error_message_is_what_pymb_raises() -> None:
    block = claim_one("docs/library.md", "text", how="compare",
                      contains="failed its CRC check")
    peer = PtyPeer()
    peer.memory.inputs[0] = 0x5FB4  # the doc's first register

    def bad_crc(slave: int, pdu: bytes, normal: bytes | None) -> list[tuple[float, bytes]]:
        assert normal is not None
        frame = peer.frame(slave, normal)
        return [(0.0, frame[:-1] + bytes([frame[-1] ^ 0xFF]))]

    peer.hook = bad_crc
    with peer, pymb.RtuClient(peer.port, 9600, timeout=0.5) as client:
        try:
            CoolPro(client, address=40).read_telemetry()
        except pymb.ModbusError as e:
            message = str(e).replace(peer.port, "/dev/ttyUSB0")
        else:
            raise AssertionError("a reply with a bad CRC was taken")
    assert_shaped(block, [message])


def test_the_storage_query_runs_on_a_logged_database(tmp_path: Path) -> None:
    block = claim_one("docs/storage.md", "sh", how="run", contains="sqlite3 data.sqlite")
    with Simulator(["coolpro", "hub:250"], seed=2) as sim:
        r = run_pymb("log", "coolpro:40", "hub:250", "--port", sim.port, "--out",
                     str(tmp_path / "data.sqlite"), "--seconds", "1", "--quiet")
    assert r.returncode == 0, r.stderr
    ran = 0
    for argv in _split_commands(block.text):
        got = subprocess.run(argv, cwd=tmp_path, capture_output=True, text=True, timeout=60,
                             check=False, env=dict(os.environ))
        assert got.returncode == 0, (argv, got.stderr)
        assert got.stdout.strip(), argv  # the database has rows for it
        ran += 1
    assert ran == block.text.count("sqlite3 data.sqlite")


def _split_commands(text: str) -> list[list[str]]:
    """The commands of a shell block: a quoted argument may span lines."""
    words = shlex.split(text, comments=True)
    out: list[list[str]] = []
    for w in words:
        if w == "sqlite3":
            out.append([w])
        else:
            out[-1].append(w)
    return out


def test_the_board_pages_configuration_check_runs(tmp_path: Path) -> None:
    """docs/board.md's check of a configuration before a reload, with
    contrib/pymb.toml as /etc/pymb/pymb.toml: its serial port moved to a
    simulated bus, its broker to a port where nothing listens (the check
    logs all the same)."""
    block = claim_one("docs/board.md", "sh", how="run", contains="--config /etc/pymb/pymb.toml")
    (argv,) = [shlex.split(line, comments=True) for line in block.lines()]
    assert argv[:2] == ["pymb", "log"]
    config = (ROOT / "contrib" / "pymb.toml").read_text()
    port = re.search(r'port = "(/dev/[^"]+)"', config)
    url = re.search(r'url = "(mqtt://[^"]+)"', config)
    assert port
    assert url
    with Simulator(["coolpro", "hub:250"], seed=5) as sim:
        (tmp_path / "pymb.toml").write_text(
            config.replace(port[1], sim.port).replace(url[1], "mqtt://127.0.0.1:1"))
        args = [str(tmp_path / "pymb.toml") if a == "/etc/pymb/pymb.toml" else
                str(tmp_path / "check.sqlite") if a == "/tmp/check.sqlite" else a
                for a in argv[1:]]
        r = run_pymb(*args, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    con = sqlite3.connect(tmp_path / "check.sqlite")
    try:
        names = {n for (n,) in con.execute("SELECT DISTINCT d.name FROM samples s "
                                           "JOIN devices d ON d.id = s.device_id")}
    finally:
        con.close()
    assert names == {"psu-a", "hub-a"}


def test_the_journal_line_of_a_silent_device(tmp_path: Path) -> None:
    """docs/board.md's journal line of a timeout: the CoolPro psu-a of bus
    line1 (contrib/pymb.toml's names) does not answer; stderr is not a
    terminal, so each event is a line on it."""
    block = claim_one("docs/board.md", "text", how="compare", contains="psu-a timeout")
    config = (ROOT / "contrib" / "pymb.toml").read_text()
    port = re.search(r'port = "(/dev/[^"]+)"', config)
    assert port
    with Simulator(["hub:250"], seed=5) as sim:  # nothing at address 40
        (tmp_path / "pymb.toml").write_text(
            '[[bus]]\nname = "line1"\nport = "PORT"\ntimeout = 1.0\n'
            '[[bus.device]]\ntype = "coolpro"\naddress = 40\nname = "psu-a"\n'
            .replace("PORT", sim.port))
        r = run_pymb("log", "--config", str(tmp_path / "pymb.toml"), "--seconds", "1.5",
                     "--out", str(tmp_path / "t.sqlite"), "--quiet", timeout=120)
        real = [line.replace(sim.port, port[1]) for line in r.stderr.splitlines()
                if "psu-a timeout" in line]
    assert r.returncode == 3, r.stderr  # psu-a delivered nothing
    assert real, r.stderr
    assert_shaped(block, real[:1])
