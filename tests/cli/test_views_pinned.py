"""``pymb read`` and ``pymb watch`` of the CoolPro and the hub, pinned byte
for byte: the text, the JSON and the 80x24 terminal screens of real
``pymb`` processes against simulators on a frozen clock (their values do
not move), compared with ``views_pinned.json``. Only what changes from run
to run is masked: the port's path, the read rate and time, the clock.

``python tests/cli/test_views_pinned.py`` writes the file again (from the
checkout's own ``pymb``: do it only for a change of output meant)."""

from __future__ import annotations

import json
import os
import re
import select
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from clikit import Pty
from conftest import run_pymb

from pymb.sim import SimClock, Simulator

PINNED = Path(__file__).with_name("views_pinned.json")

#: (name, arguments after the port); a watch's --count ends it by itself
COMMANDS: list[tuple[str, list[str]]] = [
    ("read coolpro", ["read", "coolpro"]),
    ("read coolpro --identity", ["read", "coolpro", "--identity"]),
    ("read coolpro --json", ["read", "coolpro", "--json", "--identity"]),
    ("read hub", ["read", "hub:250"]),
    ("read hub --identity", ["read", "hub:250", "--identity"]),
    ("read hub --json", ["read", "hub", "--address", "250", "--json"]),
    ("read hub humidity 1", ["read", "hub:250,humidity_unit=1"]),
    ("read hub 1.07", ["read", "hub:7,channels=50"]),
    ("read hub 1.07 100 channels", ["read", "hub:7"]),
    ("read hub 1.07 --json", ["read", "hub:7,channels=50", "--json", "--identity"]),
    ("read coolpro as hub", ["read", "hub:40"]),
    ("read hub as coolpro", ["read", "coolpro:250"]),
    ("watch coolpro", ["watch", "coolpro", "--count", "2"]),
    ("watch coolpro --identity", ["watch", "coolpro", "--count", "1", "--identity"]),
    ("watch coolpro --json", ["watch", "coolpro", "--count", "1", "--json"]),
    ("watch hub", ["watch", "hub:250", "--count", "1"]),
    ("watch hub --identity", ["watch", "hub:250", "--count", "1", "--identity"]),
    ("watch hub blocks", ["watch", "hub:250", "--count", "1", "--block", "pressure,rssi_dbm",
                          "--show", "1-12,40"]),
    ("watch hub all", ["watch", "hub:250", "--count", "1", "--block", "all"]),
    ("watch hub --json", ["watch", "hub:250", "--count", "1", "--json", "--block", "voltage",
                          "--show", "1-3"]),
    ("watch hub 1.07", ["watch", "hub:7,channels=50", "--count", "1", "--block", "all"]),
    ("watch hub 1.07 100 channels", ["watch", "hub:7", "--count", "1"]),
    ("watch hub unknown block", ["watch", "hub:250", "--count", "1", "--block", "presure"]),
    ("watch hub channel 101", ["watch", "hub:250", "--count", "1", "--show", "1-101"]),
    ("watch coolpro --block", ["watch", "coolpro", "--count", "1", "--block", "all"]),
]

#: (name, arguments after the port) run on an 80x24 terminal
SCREENS: list[tuple[str, list[str]]] = [
    ("tty watch coolpro", ["watch", "coolpro", "--count", "1"]),
    ("tty watch hub", ["watch", "hub:250", "--count", "1"]),
    ("tty watch hub all", ["watch", "hub:250", "--count", "1", "--block", "all",
                           "--identity"]),
    ("tty watch hub 1.07", ["watch", "hub:7,channels=50", "--count", "1", "--block",
                            "pressure_temperature_c,temperature_c"]),
]

_RATE = re.compile(r"\d+ reads [0-9.]+/s")


def _mask(text: str, port: str) -> str:
    text = text.replace(port, "PORT")
    text = _RATE.sub("N reads R/s", text)
    return re.sub(r'"(time_utc|read_s)": [0-9.e+-]+', r'"\1": 0', text)


def _screen(args: list[str], port: str) -> str:
    p = Pty([*args, "--port", port])
    deadline = time.monotonic() + 60
    while p.proc.poll() is None and time.monotonic() < deadline:
        p.read_more(b"\x00", 1, 0.5)  # (never shows: reads until the process ends)
    p.proc.wait(30)
    while select.select([p.master], [], [], 0.2)[0]:
        try:
            chunk = os.read(p.master, 65536)
        except OSError:
            break
        if not chunk:
            break
        p.out += chunk
    os.close(p.master)
    frames = p.out.decode().replace("\r\n", "\n").split("\x1b[H")
    # The last frame drawn, the status line (its rate's width moves the cut) masked.
    lines = frames[-1].split("\x1b[K\n")
    return "\x1b[K\n".join(["HEAD", *lines[1:]])


def outputs(sim: Simulator) -> Iterator[tuple[str, str]]:
    """(name, masked output) of each command against ``sim``."""
    port = sim.port
    for name, args in COMMANDS:
        r = run_pymb(*args, "--port", port, env={**os.environ, "COLUMNS": "80", "LINES": "24"})
        yield name, _mask(f"exit {r.returncode}\n{r.stdout}--- stderr\n{r.stderr}", port)
    for name, args in SCREENS:
        yield name, _mask(_screen(args, port), port)


def simulator() -> Simulator:
    """A CoolPro, a 100-channel hub and a 50-channel hub (V1.07) that stand still."""
    clock = SimClock(start=1000.0)
    clock.freeze()
    return Simulator(["coolpro", "hub:250", "hub:7,firmware=1.07"], seed=3, clock=clock)


@pytest.fixture(scope="module")
def got() -> dict[str, str]:
    with simulator() as sim:
        return dict(outputs(sim))


@pytest.mark.parametrize("name", [n for n, _ in COMMANDS + SCREENS])
def test_output_is_pinned(got: dict[str, str], name: str) -> None:
    want = json.loads(PINNED.read_text(encoding="utf-8"))[name]
    assert got[name] == want


if __name__ == "__main__":
    with simulator() as s:
        PINNED.write_text(json.dumps(dict(outputs(s)), indent=1, ensure_ascii=False) + "\n",
                          encoding="utf-8")
