"""docs/cli.md's command lines run, in their order, as a user runs them in
one folder: against simulated devices on a pseudo-terminal for /dev/ttyUSB0
(a CoolPro at 40 and at 3, hubs at 250 and 7) and a simulated hub on TCP
for 192.168.1.50:502, each optional part given (its first alternative). A
line that runs until stopped gets a bound (``--count``, ``--seconds``). Four
lines are only parsed (test_docs.py parses every line): ``simulate`` (it
serves until stopped; the simulators here are its own), ``demo`` (run by
test_data_doc.py), ``bench`` (minutes; tests/bench/) and ``--mqtt
mqtt://broker.lan`` (a broker by name; fleet tests run ``--mqtt``)."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

from conftest import run_pymb
from docblocks import ROOT, claim_one

from pymb.sim import Simulator, SimulatorProcess

PARSED_ONLY = ("pymb simulate ", "pymb demo ", "pymb bench ", "--mqtt mqtt://broker.lan")
BOUND = {"watch": ["--count", "2"], "log": ["--seconds", "1"]}


def _full(line: str) -> list[str]:
    """A synopsis line with every optional part given, the first of its
    alternatives, the comment dropped."""
    line = line.split("  #", 1)[0]
    line = re.sub(r"\[([^\[\]]*)\]", lambda m: m[1].split(" | ")[0], line)
    return shlex.split(line)


def test_the_command_lines_run(tmp_path: Path) -> None:
    block = claim_one("docs/cli.md", "sh", how="run", index=0)
    lines = [ln for ln in block.lines() if ln.startswith("pymb ")]
    ran = 0
    meter = claim_one("docs/map-devices.md", "toml", how="load")  # the guide's meter.toml
    (tmp_path / "meter.toml").write_text(meter.text)
    config = (ROOT / "docs" / "examples" / "buses.toml").read_text()
    with Simulator(["coolpro", "coolpro:3", "hub:250", "hub:7,firmware=1.07"], seed=3) as sim, \
            SimulatorProcess(["hub", "--tcp", "127.0.0.1:0"], quiet=True) as gateway:
        port = re.search(r'port = "(/dev/[^"]+)"', config)
        assert port
        (tmp_path / "buses.toml").write_text(config.replace(port[1], sim.port)
                                             .replace("192.168.1.50:502", gateway.endpoint))
        for line in lines:
            if any(p in line for p in PARSED_ONLY):
                continue
            argv = [sim.port if a == "/dev/ttyUSB0" else
                    gateway.endpoint if a == "192.168.1.50:502" else a
                    for a in _full(line)[1:]]
            if argv[0] == "config":
                argv = [a for a in argv if a not in ("--set-baud", "19200")]  # the address only
            r = run_pymb(*argv, *BOUND.get(argv[0], []), cwd=tmp_path, timeout=180)
            assert r.returncode == 0, (line, r.stdout[-2000:], r.stderr[-2000:])
            assert "Traceback" not in r.stderr, line
            ran += 1
    assert ran == len(lines) - 4
    for made in ("data.sqlite", "data.csv", "t.csv", "t.svg", "plant.sqlite"):
        assert (tmp_path / made).stat().st_size > 0, made
