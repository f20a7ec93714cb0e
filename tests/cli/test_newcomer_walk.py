"""What a new user meets walking through the README and the guides a second
time: a command run again on its own output, a slip in a map's name."""

from __future__ import annotations

import re
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import PYMB_ENV, ROOT, run_pymb

from pymb.collect.sqlstore import SqliteStore
from pymb.sim import Simulator


def test_demo_into_an_earlier_demos_database_counts_this_runs_faults(tmp_path: Path) -> None:
    """docs/data.md's ``pymb demo --out demo.sqlite`` run twice: the second
    summary's faults by kind are its own run's, not every run's in the file."""
    db = tmp_path / "demo.sqlite"
    r = run_pymb("demo", "--seconds", "1", "--quiet", "--out", str(db), timeout=120)
    assert r.returncode == 0, r.stderr
    con = sqlite3.connect(db)
    with con:  # an earlier run's 40 timeouts, an hour before
        con.executemany("INSERT INTO events(time_utc, monotonic, bus, kind, message) "
                        "VALUES (strftime('%s', 'now') - 3600, 0, 'psu', 'timeout', 'old')",
                        [()] * 40)
    con.close()
    r = run_pymb("demo", "--seconds", "1", "--quiet", "--out", str(db), timeout=120)
    assert r.returncode == 0, r.stderr
    seen = re.search(r"faults seen: (\d+)(?: \((.*)\))?\n", r.stdout)
    assert seen is not None, r.stdout
    by_kind = sum(int(n) for n in re.findall(r"(\d+) \w+", seen.group(2) or ""))
    assert by_kind < 40, seen.group(0)


@pytest.mark.parametrize(("argv", "said"), [
    # a shipped map's id mistyped: the closest id, in check as in show
    (["check", "eastron-sdm12"], "no shipped map 'eastron-sdm12' and no such file; did you "
     "mean 'eastron-sdm120'? (pymb map list shows the shipped maps)"),
    (["show", "eastron-sdm12"], "no shipped map 'eastron-sdm12' and no such file; did you "
     "mean 'eastron-sdm120'? (pymb map list shows the shipped maps)"),
    # a file that is not there: the file's own line, not every shipped id
    (["show", "nosuch.toml"], "nosuch.toml: cannot read the map: No such file or directory"),
    (["check", "nosuch.toml"], "nosuch.toml: cannot read the map: No such file or directory"),
    (["show", "maps/meter"], "maps/meter: cannot read the map: No such file or directory"),
])
def test_a_map_that_is_neither_shipped_nor_a_file(argv: list[str], said: str) -> None:
    r = run_pymb("map", *argv, timeout=60)
    assert (r.returncode, r.stdout, r.stderr) == (2, "", f"pymb map: {said}\n")


@pytest.mark.parametrize(("argv", "fixed"), [
    (["--port", "/dev/ttyUSB0", "read", "coolpro"], "pymb read coolpro --port /dev/ttyUSB0"),
    # an option the command takes was 'unrecognized; did you mean' itself
    (["--quiet", "log", "hub:250", "--tcp", "127.0.0.1:1"],
     "pymb log hub:250 --tcp 127.0.0.1:1 --quiet"),
    (["--out", "my data.csv", "export", "d.sqlite"], "pymb export d.sqlite --out 'my data.csv'"),
])
def test_options_before_the_command(argv: list[str], fixed: str) -> None:
    """One line with the command line in its order; nothing is opened."""
    r = run_pymb(*argv, timeout=60)
    assert (r.returncode, r.stdout) == (2, "")
    assert r.stderr.splitlines() == ["usage: pymb [-h] [--version] COMMAND ...",
                                     f"pymb: error: options go after the command: {fixed}"]


def test_ctrl_c_while_pymb_itself_loads(tmp_path: Path) -> None:
    """The installed ``pymb`` command, as its console script runs it (the
    entry point pyproject.toml names), with a real SIGINT while the package's
    C extension is imported: exit 130, no traceback."""
    script = f"""
import builtins, importlib, os, signal, sys, tomllib
signal.signal(signal.SIGINT, signal.default_int_handler)  # a terminal's Ctrl-C
with open({str(ROOT / "pyproject.toml")!r}, "rb") as f:
    module, name = tomllib.load(f)["project"]["scripts"]["pymb"].split(":")
real = builtins.__import__
def loading(what, *args, **kw):
    if what == "pymb._native":
        builtins.__import__ = real
        os.kill(os.getpid(), signal.SIGINT)
    return real(what, *args, **kw)
builtins.__import__ = loading
sys.argv = ["pymb", "info", "data.sqlite"]
entry = getattr(importlib.import_module(module), name)
sys.exit(entry())
"""
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                       timeout=60, env=PYMB_ENV, cwd=tmp_path, check=False)
    assert (r.returncode, r.stderr) == (130, "")


@pytest.mark.parametrize("argv", [["info"], ["export", "--csv", "out.csv"],
                                  ["plot", "hub-1", "temperature_c", "--channel", "1"]])
def test_the_data_commands_on_what_pymb_collect_wrote(tmp_path: Path, argv: list[str]) -> None:
    """docs/collect.md's SQLite file given to ``pymb info`` (export, plot):
    said to be the collector's, with what reads it, not 'not written by pymb'."""
    db = tmp_path / "fleet.sqlite"
    SqliteStore(str(db)).close()  # the collector's tables, as pymb collect makes them
    r = run_pymb(argv[0], str(db), *argv[1:], timeout=60, cwd=tmp_path)
    assert (r.returncode, r.stdout) == (2, "")
    assert r.stderr == (f"pymb {argv[0]}: {db} is what pymb collect writes, not pymb log: query "
                        "its pymb_values table (pymb_latest view) with SQL\n")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fleet.sqlite"]


def test_collect_into_a_pymb_log_database_leaves_it_alone(tmp_path: Path) -> None:
    """``pymb collect --out data.sqlite``, the name the logger's database has:
    refused before the broker is asked, the file byte for byte as it was."""
    db = tmp_path / "data.sqlite"
    with Simulator(["coolpro"], transport="tcp", seed=1) as sim:
        r = run_pymb("log", "coolpro", "--tcp", f"127.0.0.1:{sim.tcp_port}", "--seconds", "0.5",
                     "--quiet", "--out", str(db), timeout=60)
    assert r.returncode == 0, r.stderr
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    r = run_pymb("collect", "--mqtt", "mqtt://127.0.0.1:1", "--out", str(db), timeout=60)
    assert (r.returncode, r.stdout) == (2, "")
    assert r.stderr == (f"pymb collect: {db} is a SQLite database pymb collect did not write: "
                        "refusing to add to it; choose another --out\n")
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before


@pytest.mark.parametrize(("line", "said"), [
    ('profle = "plain"', "[mqtt]: unknown key 'profle'; did you mean 'profile'?"),
    ("password = \"secret\"", "[mqtt]: unknown key 'password'; did you mean 'password_file'?"),
])
def test_a_typo_in_the_mqtt_table(tmp_path: Path, line: str, said: str) -> None:
    """docs/cli.md: an unknown key is an error that names it and the closest
    known one, in ``[mqtt]`` as in every other table; nothing is opened."""
    config = tmp_path / "buses.toml"
    config.write_text(f'[output]\npath = "plant.sqlite"\n[mqtt]\nurl = "mqtt://127.0.0.1:1"\n'
                      f'{line}\n[[bus]]\ntcp = "127.0.0.1:1"\n  [[bus.device]]\n'
                      '  type = "coolpro"\n')
    r = run_pymb("log", "--config", str(config), timeout=60, cwd=tmp_path)
    assert (r.returncode, r.stdout, r.stderr) == (2, "", f"pymb log: {config}: {said}\n")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["buses.toml"]


@pytest.mark.parametrize(("toml", "said"), [
    ('[bus]\ntcp = "127.0.0.1:1"\n', "[bus] is one table; write [[bus]], one for each bus"),
    ('[[bus]]\ntcp = "127.0.0.1:1"\n  [bus.device]\n  type = "coolpro"\n',
     "bus 1: [bus.device] is one table; write [[bus.device]], one for each device"),
    ('[[output]]\npath = "p.sqlite"\n[[bus]]\ntcp = "127.0.0.1:1"\n',
     "[[output]] is a list of tables; write [output], once"),
])
def test_brackets_of_a_table_in_the_toml_file(tmp_path: Path, toml: str, said: str) -> None:
    """``[bus]`` where docs/cli.md writes ``[[bus]]`` (and the other way):
    said in the file's words, not 'bus has the wrong type ({...})'."""
    config = tmp_path / "buses.toml"
    config.write_text(toml)
    r = run_pymb("log", "--config", str(config), timeout=60, cwd=tmp_path)
    assert (r.returncode, r.stdout, r.stderr) == (2, "", f"pymb log: {config}: {said}\n")


def test_demo_into_a_folder_that_does_not_exist(tmp_path: Path) -> None:
    """One line and exit 5, as ``pymb log`` says it, before the simulators
    start (no 'simulated CoolPro on ...' line first)."""
    out = tmp_path / "no-such-folder" / "demo.sqlite"
    r = run_pymb("demo", "--out", str(out), timeout=60)
    assert (r.returncode, r.stdout) == (5, "")
    assert r.stderr == (f"pymb demo: cannot open the database {out}: its directory {out.parent} "
                        "does not exist; create it, or mount the disk that holds it (or log to "
                        "another --out)\n")


@pytest.mark.parametrize(("word", "close"), [("reed", "read"), ("sumulate", "simulate"),
                                             ("exprot", "export")])
def test_a_mistyped_command_gets_the_closest(word: str, close: str) -> None:
    r = run_pymb(word, "coolpro", "--port", "/dev/ttyUSB0", timeout=60)
    assert (r.returncode, r.stdout) == (2, "")
    assert r.stderr.splitlines() == ["usage: pymb [-h] [--version] COMMAND ...",
                                     f"pymb: error: unknown command {word!r}; did you mean "
                                     f"{close!r}?"]


def test_a_word_far_from_every_command_gets_argparse_s_choices() -> None:
    # 'rexx' is 0.5 like 'read' (difflib's ratio): close enough for a map's
    # names, not for a command's
    r = run_pymb("rexx", "coolpro", timeout=60)
    assert (r.returncode, r.stdout) == (2, "")
    assert "did you mean" not in r.stderr
    assert "pymb: error: argument COMMAND: invalid choice: 'rexx' (choose from" in r.stderr


def test_a_typo_in_a_devices_type_in_the_toml_file(tmp_path: Path) -> None:
    """The closest type, then what a type may be: one sentence, no '?;'."""
    config = tmp_path / "buses.toml"
    config.write_text('[[bus]]\ntcp = "127.0.0.1:1"\n  [[bus.device]]\n  type = "colpro"\n')
    r = run_pymb("log", "--config", str(config), timeout=60, cwd=tmp_path)
    assert (r.returncode, r.stdout) == (2, "")
    assert r.stderr == (f"pymb log: {config}: bus 1, device 1: unknown type 'colpro'; did you "
                        "mean 'coolpro'? (give coolpro, hub, a map's id or map = \"FILE\")\n")
