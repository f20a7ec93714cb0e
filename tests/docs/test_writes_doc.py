"""docs/writes.md's examples run: its TOML block is the inverter every
example uses, its Python block runs against a simulated inverter, and each
``$ pymb`` line of its shell block runs as a user would run it against the
``pymb simulate`` line's simulator, its output compared with the lines the
page shows under it."""

from __future__ import annotations

import fnmatch
import json
import re
import shlex
import tomllib
from pathlib import Path

from conftest import run_pymb
from docblocks import claim, claim_one

from pymb import maps
from pymb.logger.config import config_from_toml
from pymb.sim import SimulatorProcess

INVERTER = claim_one("docs/writes.md", "toml", how="load", contains="id = \"acme-inverter\"").text
CODE = claim_one("docs/writes.md", "python", how="run").text
SHELL = claim_one("docs/writes.md", "sh", how="run", contains="pymb write")
ALLOW = claim_one("docs/writes.md", "toml", how="load", contains="[writes]").text
COMMANDS = claim("docs/writes.md", "json", how="parse")
SYNOPSIS = claim_one("docs/writes.md", "text", how="check", contains="pymb write DEVICE").text


def test_the_synopsis_names_every_option_of_pymb_write() -> None:
    shown = set(re.findall(r"--[a-z-]+", SYNOPSIS))
    helped = set(re.findall(r"--[a-z-]+", run_pymb("write", "--help").stdout))
    # the synopsis leaves out what every command with a line has (--parity, --timeout)
    assert shown == helped - {"--help", "--parity", "--timeout"}


def test_the_map_loads() -> None:
    m = maps.loads(INVERTER, source="inverter.toml")
    assert m.points["frequency_setpoint_hz"].max_writes_per_hour == 4
    assert m.points["power_limit_pct"].max_writes_per_hour is None


def test_the_python_example_runs() -> None:
    exec(compile(CODE, "docs/writes.md", "exec"), {"INVERTER": INVERTER})


def test_the_shell_example_runs_and_prints_what_it_shows(tmp_path: Path) -> None:
    (tmp_path / "inverter.toml").write_text(INVERTER)
    commands: list[tuple[str, list[str]]] = []
    for line in SHELL.lines():
        if line.startswith("$ "):
            commands.append((line[2:].rstrip("\n"), []))
        else:
            commands[-1][1].append(line.rstrip("\n"))
    simulate = commands[0][0]
    assert simulate.startswith("pymb simulate")
    assert commands[0][1] == []
    endpoint = simulate.split("--tcp ")[1].split()[0]
    args = shlex.split(simulate)[2:]
    args[args.index("--tcp") + 1] = "127.0.0.1:0"
    args[args.index("inverter.toml")] = str(tmp_path / "inverter.toml")
    assert len(commands) == 5
    with SimulatorProcess(args, quiet=True) as sim:
        for line, shown in commands[1:]:
            argv = shlex.split(line.replace(endpoint, sim.endpoint))[1:]
            r = run_pymb(*argv, cwd=tmp_path)
            assert (r.returncode, r.stderr) == (0, ""), line
            assert r.stdout.splitlines() == shown, line


def test_the_allow_list_loads_as_a_logger_configuration(tmp_path: Path) -> None:
    bus = '[[bus]]\nname = "b"\ntcp = "127.0.0.1:5020"\n[[bus.device]]\ntype = "eastron-sdm120"\n'
    cfg = config_from_toml(tomllib.loads(ALLOW + bus), tmp_path / "log.toml")
    assert cfg.allow_writes == ("acme-inverter-1/power_limit_pct", "meter-3/*")


def test_the_command_and_results_are_what_the_logger_takes_and_publishes() -> None:
    command, results = (json.loads(b.text) for b in COMMANDS[:1]), COMMANDS[1]
    for c in command:
        assert set(c) == {"id", "values"}
    for line in results.lines():
        doc = json.loads(line)
        assert set(doc) == ({"id", "ok", "values", "time"} if doc["ok"] else
                            {"id", "ok", "reason", "error", "values", "time"})


def test_the_commands_write_the_inverter_of_the_page(tmp_path: Path) -> None:
    """The allow list, the command and its results name the page's inverter
    (logged under its default name, acme-inverter-1) and points it can write;
    a refusal says what ``pymb write`` says of the same value."""
    m = maps.loads(INVERTER, source="inverter.toml")
    (tmp_path / "inverter.toml").write_text(INVERTER)
    allow = tomllib.loads(ALLOW)["writes"]["allow"]
    named: set[str] = set()
    for block in COMMANDS[:2]:
        for line in block.lines():
            doc = json.loads(line)
            named |= set(doc["values"])
            if "error" in doc:
                point, value = re.fullmatch(r"acme-inverter: point '(\w+)': (\S+) is outside .*",
                                            doc["error"]).groups()  # type: ignore[union-attr]
                named.add(point)
                r = run_pymb("write", "--map", "inverter.toml", "acme-inverter:1",
                             f"{point}={value}", "--dry-run", "--tcp", "127.0.0.1:1",
                             cwd=tmp_path)
                assert r.stderr == f"pymb write: {doc['error']}\n"
    assert named
    for point in named:
        assert m.points[point].access in ("rw", "w"), point
        assert any(fnmatch.fnmatch(f"acme-inverter-1/{point}", p) for p in allow), point
