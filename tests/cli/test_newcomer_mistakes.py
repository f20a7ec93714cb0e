"""A newcomer's slips on the command line: one line in the command's own name
and usage, exit 2, no traceback; Ctrl-C at any moment is exit 130."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest
from clikit import Pty, digest
from conftest import PYMB_ENV, ROOT, run_pymb

import pymb
from pymb.devices import CoolPro
from pymb.sim import Simulator, SimulatorProcess


@pytest.mark.parametrize(("argv", "said"), [
    (["log", "coolpro", "--port", "/dev/null", "--formt", "csv"],
     "pymb log: error: unrecognized arguments: --formt csv; did you mean --format?"),
    (["read", "coolpro", "--tcp", "127.0.0.1:1", "--jsn"],
     "pymb read: error: unrecognized arguments: --jsn; did you mean --json?"),
    (["export", "data.sqlite", "--csv", "x.csv", "--devcie", "hub:250"],
     "pymb export: error: unrecognized arguments: --devcie hub:250; did you mean --device?"),
    # nothing close: no guess
    (["log", "coolpro", "--port", "/dev/null", "--count", "2"],
     "pymb log: error: unrecognized arguments: --count 2"),
    (["--bogus"], "pymb: error: unrecognized arguments: --bogus"),
])
def test_an_option_the_command_does_not_take(argv: list[str], said: str) -> None:
    r = run_pymb(*argv, timeout=60)
    assert r.returncode == 2
    assert r.stdout == ""
    lines = r.stderr.strip().splitlines()
    assert lines[-1] == said
    assert lines[0].startswith(f"usage: pymb {argv[0]}" if argv[0][0] != "-" else "usage: pymb ")
    assert "Traceback" not in r.stderr


def test_ctrl_c_while_the_command_loads() -> None:
    """A real SIGINT while ``pymb info``'s module is imported, before any
    argument is parsed: exit 130, no traceback."""
    script = """
import importlib, os, signal, sys
from pymb import cli
real = importlib.import_module
def loading(name, package=None):
    if name.startswith("pymb.commands."):
        os.kill(os.getpid(), signal.SIGINT)
    return real(name, package)
importlib.import_module = loading
sys.exit(cli.main(["info", "data.sqlite"]))
"""
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                       timeout=60, env=PYMB_ENV, check=False)
    assert r.returncode == 130, r.stderr
    assert "Traceback" not in r.stderr


def test_map_check_of_a_copied_shipped_map(tmp_path: Path) -> None:
    """A shipped map copied to be edited keeps the shipped id: ``map check``
    says what ``read --map`` would refuse, not 'valid'."""
    copy = tmp_path / "my-sdm120.toml"
    copy.write_text((ROOT / "pymb" / "maps" / "builtin" / "eastron-sdm120.toml")
                    .read_text(encoding="utf-8"), encoding="utf-8")
    said = (f"{copy}: device id 'eastron-sdm120' is a device pymb ships; "
            "give the map another id")
    r = run_pymb("map", "check", str(copy), timeout=60)
    assert (r.returncode, r.stdout, r.stderr) == (2, "", f"pymb map: {said}\n")
    r = run_pymb("read", "--map", str(copy), "eastron-sdm120", "--tcp", "127.0.0.1:1",
                 timeout=60)
    assert r.returncode == 2
    assert "is a device pymb ships; give the map another id" in r.stderr
    # with an id of its own it is valid
    copy.write_text(copy.read_text(encoding="utf-8").replace(
        'id = "eastron-sdm120"', 'id = "my-sdm120"'), encoding="utf-8")
    r = run_pymb("map", "check", str(copy), timeout=60)
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith(f"{copy}: my-sdm120 ")


def test_a_map_device_at_an_address_where_another_device_answers() -> None:
    """``pymb read generic-vfd:40`` where a CoolPro answers (exception 02 for
    every point of the drive's map): no value at all is exit 3 saying what
    answers there, not a table of 'unsupported' and exit 0; ``watch`` counts
    it as a fault and waits before the next try."""
    with Simulator(["coolpro", "generic-vfd:5", "eastron-sdm630:1"], transport="tcp",
                   seed=1) as sim:
        tcp = f"127.0.0.1:{sim.tcp_port}"
        r = run_pymb("read", "generic-vfd:40", "--tcp", tcp, timeout=60)
        assert (r.returncode, r.stdout) == (3, "")
        assert r.stderr == (f"pymb read: no value from generic-vfd:40 on {tcp}: address 40 "
                            "answers like a CoolPro, not generic-vfd (serial 12345, firmware "
                            "1.0.0, hardware rev 1, made 2026-06-01)\n")
        # a meter's map read at the drive's address: the drive refuses every point
        r = run_pymb("read", "eastron-sdm120:5", "--tcp", tcp, timeout=60)
        assert r.returncode == 3
        # named by the shipped maps' identify rules, as pymb scan names it
        assert r.stderr == (f"pymb read: no value from eastron-sdm120:5 on {tcp}: address 5 "
                            "answers like generic-vfd (Delta (layout) VFD-E / VFD-ED compatible: "
                            "output_frequency_hz 49.98), not eastron-sdm120: read it as "
                            "generic-vfd:5\n")
        # an energy meter has registers where a CoolPro keeps its identity: it
        # is named by its map all the same
        r = run_pymb("read", "hub:1", "--tcp", tcp, timeout=60)
        assert r.returncode == 3
        assert "address 1 answers like eastron-sdm630 (Eastron SDM630" in r.stderr
        assert r.stderr.endswith("not a hub: read it as eastron-sdm630:1\n")
        r = run_pymb("watch", "generic-vfd:40", "--tcp", tcp, "--count", "2", "--json",
                     timeout=60)
        assert r.returncode == 3, r.stderr
        first, second = (json.loads(line) for line in r.stdout.splitlines())
        assert first["error"].endswith("not generic-vfd (serial 12345, firmware 1.0.0, "
                                       "hardware rev 1, made 2026-06-01); next try in 0.5 s")
        assert "values" not in second
        assert second["time_utc"] - first["time_utc"] >= 0.5
        # the device itself reads as ever
        r = run_pymb("read", "generic-vfd:5", "--tcp", tcp, "--json", timeout=60)
        assert r.returncode == 0, r.stderr
        assert json.loads(r.stdout)["states"]["frequency_setpoint_hz"] == "value"


def test_log_without_out(tmp_path: Path) -> None:
    """``pymb log`` without ``--out``: SQLite into a new dated file in the
    current folder, a text format to stdout (docs/cli.md)."""
    with Simulator(["coolpro"], transport="tcp", seed=1) as sim:
        tcp = f"127.0.0.1:{sim.tcp_port}"
        r = run_pymb("log", "coolpro", "--tcp", tcp, "--seconds", "0.5", "--quiet",
                     cwd=tmp_path, timeout=60)
        assert r.returncode == 0, r.stderr
        made = [p.name for p in tmp_path.iterdir() if not p.name.startswith(".")]
        assert len(made) == 1, made
        assert re.fullmatch(r"pymb-\d{8}-\d{6}\.sqlite", made[0]), made
        r = run_pymb("log", "coolpro", "--tcp", tcp, "--seconds", "0.5", "--quiet",
                     "--format", "csv", cwd=tmp_path, timeout=60)
        assert r.returncode == 0, r.stderr
        assert r.stdout.startswith("time_utc,time,bus,device,")
        assert len([p for p in tmp_path.iterdir() if not p.name.startswith(".")]) == 1
    # and the help says so
    r = run_pymb("log", "--help", timeout=60)
    assert " ".join(r.stdout.split()).count(
        "default: a new pymb-YYYYmmdd-HHMMSS.sqlite here, stdout for the other formats") == 1


@pytest.mark.parametrize(("answer", "code"), [(b"\x04", 1), (b"n\n", 1), (None, 130)])
def test_config_confirmation_answered(answer: bytes | None, code: int) -> None:
    """``pymb config``'s question on a terminal, answered with Ctrl-D, no or
    Ctrl-C: nothing is written, no traceback, exit 1 (130 for Ctrl-C), and
    the shell's prompt is left on a line of its own."""
    with Simulator(["coolpro"], transport="tcp", seed=1) as sim:
        term = Pty(["config", "coolpro:40", "--tcp", f"127.0.0.1:{sim.tcp_port}",
                    "--set-address", "43"])
        assert term.read_until(b"[y/N] "), term.out
        # a person answers a moment after the question (a signal before input()
        # waits in its select() is CPython's readline race, not pymb's)
        time.sleep(0.5)
        if answer is None:
            term.interrupt()
        else:
            os.write(term.master, answer)
            assert term.proc.wait(30) == code
            term.interrupt()  # (ended: reads what is left)
        assert term.proc.returncode == code
        text = term.out.decode()
        assert "Traceback" not in text
        assert text.endswith("\r\n"), text
        if code == 1:
            assert text.endswith("nothing written\r\n"), text
        with pymb.TcpClient("127.0.0.1", sim.tcp_port, slave=40) as c:
            assert CoolPro(c, 40).read_telemetry()  # still at its address


def test_a_terminal_that_cannot_show_every_character() -> None:
    """stdout in ASCII (``PYTHONIOENCODING=ascii``, an old terminal): a
    reading with its ``°C`` is shown with ``?`` for what it cannot write, not
    ended by UnicodeEncodeError."""
    with Simulator(["coolpro"], transport="tcp", seed=1) as sim:
        r = run_pymb("read", "coolpro", "--tcp", f"127.0.0.1:{sim.tcp_port}", timeout=60,
                     env=dict(PYMB_ENV, PYTHONIOENCODING="ascii"))
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    assert re.search(r"^Temperature +[\d.]+ \?C$", r.stdout, re.M), r.stdout


def test_a_serial_console_that_says_0x0(tmp_path: Path) -> None:
    """A board's serial console reports 0 columns and 0 lines: ``watch`` and
    ``log``'s status line draw as on 80x24, not an ellipsis alone."""
    with Simulator(["coolpro"], transport="tcp", seed=1) as sim:
        tcp = f"127.0.0.1:{sim.tcp_port}"
        term = Pty(["watch", "coolpro", "--tcp", tcp], cols=0, rows=0)
        assert term.read_until(b"Input Voltage"), term.out
        assert term.read_more(b"reads", 2), term.out
        assert term.interrupt() < 30
        assert "Input Voltage" in "\n".join(term.screen())
        term = Pty(["log", "coolpro", "--tcp", tcp, "--out", str(tmp_path / "c.sqlite")],
                   cols=0, rows=0)
        assert term.read_more(b" samples ", 2), term.out
        assert term.interrupt() < 30
        assert term.proc.returncode == 0, term.out
        assert re.search(rb"\d+ samples +[\d.]+/s +faults 0", term.out), term.out


@pytest.mark.parametrize(("name", "fmt", "said"), [
    ("readings.csv", None, "readings.csv is named like a CSV file but the format is sqlite: "
     "give --format csv"),
    ("readings.json", None, "is named like a JSON Lines file but the format is sqlite"),
    ("data.sqlite", "csv", "data.sqlite is named like a SQLite file but the format is csv: "
     "give --format sqlite"),
    ("data.db", "jsonl", "is named like a SQLite file but the format is jsonl"),
])
def test_log_into_a_name_of_another_format(tmp_path: Path, name: str, fmt: str | None,
                                           said: str) -> None:
    """``pymb log ... --out readings.csv`` without ``--format csv``: refused in
    one line before anything is made, not a SQLite database named .csv."""
    args = ["log", "coolpro", "--tcp", "127.0.0.1:1", "--seconds", "1",
            "--out", str(tmp_path / name), *(["--format", fmt] if fmt else [])]
    r = run_pymb(*args, timeout=60)
    assert r.returncode == 2
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert said in r.stderr
    assert list(tmp_path.iterdir()) == []
    # the same in a configuration file
    cfg = tmp_path / "log.toml"
    cfg.write_text(f'[output]\npath = "{name}"\n' + (f'format = "{fmt}"\n' if fmt else "") +
                   '[[bus]]\ntcp = "127.0.0.1:1"\n  [[bus.device]]\n  type = "coolpro"\n')
    r = run_pymb("log", "--config", str(cfg), "--seconds", "1", timeout=60)
    assert r.returncode == 2
    assert said in r.stderr
    assert [p.name for p in tmp_path.iterdir()] == ["log.toml"]


def test_log_into_a_name_of_its_format(tmp_path: Path) -> None:
    with Simulator(["coolpro"], transport="tcp", seed=1) as sim:
        for name, fmt in (("r.csv", "csv"), ("r.jsonl", "jsonl"), ("r.db", "sqlite"),
                          ("r.txt", "influx"), ("r.log", "csv")):
            r = run_pymb("log", "coolpro", "--tcp", f"127.0.0.1:{sim.tcp_port}", "--seconds",
                         "0.3", "--quiet", "--format", fmt, "--out", str(tmp_path / name),
                         timeout=60)
            assert r.returncode == 0, (name, r.stderr)
            assert (tmp_path / name).stat().st_size > 0


@pytest.mark.parametrize(("name", "said"), [
    ("notes.txt", "notes.txt exists and is not a SQLite database: refusing to write into it"),
    ("demo.csv", "demo.csv is named like a CSV file but the format is sqlite: give it another "
     "name"),
])
def test_demo_out_refused_before_anything_starts(tmp_path: Path, name: str, said: str) -> None:
    out = tmp_path / name
    if name == "notes.txt":
        out.write_text("my notes\n")
    r = run_pymb("demo", "--out", str(out), timeout=60)
    assert r.returncode == 2
    assert r.stderr == f"pymb demo: {tmp_path}/{said}" + (
        "; choose another --out\n" if name == "notes.txt" else "\n")
    assert sorted(p.name for p in tmp_path.iterdir()) == (
        ["notes.txt"] if name == "notes.txt" else [])
    if name == "notes.txt":
        assert out.read_text() == "my notes\n"


@pytest.mark.parametrize(("argv", "said"), [
    (["demo", "--out", "-"], "pymb demo: SQLite needs a file; give --out a file name\n"),
    (["log", "coolpro", "--port", "/dev/null", "--out", "-"],
     "pymb log: SQLite needs a file; use --format csv, jsonl or influx for stdout\n"),
])
def test_sqlite_to_stdout_is_one_line_before_anything_starts(argv: list[str], said: str) -> None:
    """``--out -`` with SQLite: refused before a simulator or a line is opened."""
    r = run_pymb(*argv, timeout=60)
    assert (r.returncode, r.stdout, r.stderr) == (2, "", said)


def test_demo_mqtt_broker_unreachable_is_a_connection_failure(tmp_path: Path) -> None:
    """Exit 4, as ``pymb collect`` says an unreachable broker, not 2."""
    pytest.importorskip("paho.mqtt")
    r = run_pymb("demo", "--seconds", "1", "--mqtt", "mqtt://127.0.0.1:1",
                 "--out", str(tmp_path / "d.sqlite"), timeout=60)
    assert r.returncode == 4, r.stderr
    assert r.stderr.strip().splitlines()[-1].startswith(
        "pymb demo: --mqtt: cannot connect to mqtt://127.0.0.1:1: ")
    assert "Traceback" not in r.stderr


def test_unknown_device_says_the_closest_first() -> None:
    """A typo in the TYPE: the closest name first, on a line a terminal shows
    whole, with where to find the rest (not the dozens of shipped ids)."""
    r = run_pymb("read", "hubb", "--tcp", "127.0.0.1:1", timeout=60)
    assert r.returncode == 2
    assert r.stderr.startswith("pymb read: unknown device 'hubb'; did you mean 'hub'? A device "
                               "is TYPE[:ADDRESS][,key=value...]")
    assert "`pymb map list` shows the shipped maps" in r.stderr
    assert len(r.stderr) < 240, r.stderr
    r = run_pymb("read", "xyz", "--tcp", "127.0.0.1:1", timeout=60)
    assert r.stderr.startswith("pymb read: unknown device 'xyz': a device is")


def test_map_list_fits_the_terminal() -> None:
    """``pymb map list`` on 80 columns: a line a map, none wrapped; piped,
    each line whole with the document it was written from."""
    term = Pty(["map", "list"], cols=80, rows=24)
    term.proc.wait(60)
    term.interrupt()  # (ended: reads what is left)
    assert term.proc.returncode == 0
    lines = term.out.decode().splitlines()
    assert len(lines) > 30
    assert all(len(line) <= 80 for line in lines), max(lines, key=len)
    assert any(line.startswith("abb-acs580 ") for line in lines)
    r = run_pymb("map", "list", timeout=60)
    assert "ABB ACS580 firmware manual" in r.stdout


@pytest.mark.parametrize(("spec", "said"), [
    ("hub:1,channels=0", "hub: option 'channels' must be 1..100, got 0"),
    ("hub:1,humidity_unit=2", "hub: option 'humidity_unit' must be one of 1, 0.1, got 2"),
])
def test_an_option_value_of_a_shipped_device_is_named_by_its_type(spec: str, said: str) -> None:
    """The device TYPE the user gave, not the loader's 'builtin:hub'."""
    for command in ("read", "write"):
        extra = ["temperature_c_1=1"] if command == "write" else []
        r = run_pymb(command, spec, *extra, "--tcp", "127.0.0.1:1", timeout=60)
        assert (r.returncode, r.stdout, r.stderr) == (
            2, "", f"pymb {command}: {spec!r}: {said}\n")


@pytest.mark.parametrize(("transport", "said"), [
    ("--tcp", "cannot open [::1]:1: connection refused"),
    ("--udp", "on [::1]:1/udp: connection refused"),
])
def test_an_ipv6_endpoint_is_named_as_it_is_written(transport: str, said: str) -> None:
    """``--tcp [::1]:1`` fails naming ``[::1]:1``, the spelling it takes, never
    ``::1:1``, which the same command refuses."""
    r = run_pymb("read", "coolpro", transport, "[::1]:1", "--timeout", "0.5")
    assert r.returncode == 4, r.stderr
    assert said in r.stderr, r.stderr
    assert "::1:1" not in r.stderr.replace("[::1]:1", "")


@pytest.mark.parametrize("command", [["log", "coolpro", "--tcp", "127.0.0.1:1"],
                                     ["demo", "--seconds", "1"]])
def test_logging_into_a_collector_database_names_it(tmp_path: Path, command: list[str]) -> None:
    """A database ``pymb collect`` made is refused as what it is, as info and
    export say, not as one pymb did not write; it is left as it was."""
    db = tmp_path / "fleet.sqlite"
    made = run_pymb("collect", "--mqtt", "mqtt://127.0.0.1:1", "--out", str(db))
    assert made.returncode == 4, made.stderr  # no broker: the database is made first
    before = digest(db)
    r = run_pymb(*command, "--out", str(db))
    assert r.returncode == 2, r.stderr
    assert r.stderr == (f"pymb {command[0]}: {db} is what pymb collect writes, not pymb log: "
                        "refusing to add to it; choose another --out\n")
    assert digest(db) == before


def test_scan_with_a_long_timeout_and_the_confirmation_bound() -> None:
    """``pymb scan --timeout 61`` (a slow gateway) scans: the confirmation's
    default follows --timeout up to its own bound, never refusing an option that
    was not given; a --confirm-timeout past that bound is named with it."""
    with SimulatorProcess(["hub:2", "--tcp", "127.0.0.1:0"], quiet=True) as sim:
        r = run_pymb("scan", "--tcp", sim.endpoint, "--range", "2", "--timeout", "61",
                     "--json")
        assert r.returncode == 0, r.stderr
        assert [d["address"] for d in json.loads(r.stdout)["found"]] == [2]
        r = run_pymb("scan", "--tcp", sim.endpoint, "--range", "2", "--confirm-timeout", "61")
        assert (r.returncode, r.stderr) == (
            2, "pymb scan: --confirm-timeout must be more than 0 and at most 60 s, got 61\n")
