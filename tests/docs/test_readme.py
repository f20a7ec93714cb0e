"""The README's examples run: its Python example against simulated devices
on a pseudo-terminal in place of /dev/ttyUSB0, its C example compiled
against csrc/ and run the same way; and the README stays a front door."""

from __future__ import annotations

import contextlib
import io
import re
import shlex
import shutil
import sqlite3
import subprocess
from pathlib import Path

import pytest
from conftest import run_pymb
from docblocks import claim_one

from pymb.devices import State
from pymb.sim import Simulator, SimulatorProcess

ROOT = Path(__file__).resolve().parents[2]
README = (ROOT / "README.md").read_text()


def block(lang: str) -> str:
    if lang == "python":
        return claim_one("README.md", "python", how="run").text
    return claim_one("README.md", "c", how="compile").text


def test_the_readme_is_a_front_door() -> None:
    assert len(README.splitlines()) <= 300
    for link in re.findall(r"\]\(((?:docs/|CHANGELOG)[^)#]*)", README):
        assert (ROOT / link).exists(), link


def test_the_readme_names_every_extra() -> None:
    """The install section's "Extras:" sentence names each extra pyproject.toml
    has, so that a newcomer who follows it finds the one ``pymb collect`` needs."""
    import tomllib
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"][
        "optional-dependencies"]
    sentence = README[README.index("Extras: "):].split(". ", 1)[0]
    named = re.findall(r"`(\w+)`(?: \(|,)", sentence.replace("\n", " "))
    assert sorted(named) == sorted(extras), sentence


def test_the_python_example_runs() -> None:
    code = block("python")
    assert len(code.splitlines()) <= 12
    with Simulator(["coolpro", "hub:1"], seed=5) as sim:
        out = io.StringIO()
        with contextlib.redirect_stdout(out):
            exec(compile(code.replace("/dev/ttyUSB0", sim.port), "README.md", "exec"), {})
    first, second = out.getvalue().splitlines()
    assert len(first.split()) == 4
    assert second.split()[1] in State.__members__


@pytest.mark.skipif(shutil.which("make") is None or shutil.which("cc") is None,
                    reason="needs make and a C compiler")
def test_the_c_example_builds_and_runs(tmp_path: Path) -> None:
    subprocess.run(["make", "-s", "-C", str(ROOT / "csrc"), f"B={tmp_path}", "lib"],
                   check=True, capture_output=True, timeout=600)
    with Simulator(["coolpro"], seed=5) as sim:
        (tmp_path / "app.c").write_text(block("c").replace("/dev/ttyUSB0", sim.port))
        flags = subprocess.run(["pkg-config", "--cflags", "--libs", "libmodbus"], check=True,
                               capture_output=True, text=True).stdout.split()
        subprocess.run(["cc", "-std=c99", "-Wall", "-Werror", "-o", str(tmp_path / "app"),
                        str(tmp_path / "app.c"), f"-I{ROOT / 'csrc'}",
                        str(tmp_path / "libpymb.a"), *flags, "-lm"],
                       check=True, capture_output=True, timeout=120)
        run = subprocess.run([str(tmp_path / "app")], capture_output=True, text=True,
                             timeout=60, check=False)
    assert run.returncode == 0, run.stderr
    assert re.fullmatch(r"input voltage \d+\.\d{3} V\n", run.stdout), run.stdout


def test_the_logger_lines_run(tmp_path: Path) -> None:
    """The README's logger block as a user runs it, each line once: against a
    simulated CoolPro and hub on a pseudo-terminal for /dev/ttyUSB0, and for
    buses.toml its two buses (the serial one and the TCP gateway) moved to
    simulators. A line that runs until stopped gets a bound (--count,
    --seconds)."""
    block = claim_one("README.md", "sh", how="run", contains="pymb read hub:250")
    commands: list[list[str]] = []
    for word in shlex.split(block.text, comments=True):
        if word in ("pymb", "sqlite3"):
            commands.append([word])
        else:
            commands[-1].append(word)
    assert [c[:2] for c in commands] == [["pymb", "read"], ["pymb", "watch"], ["pymb", "log"],
                                         ["pymb", "log"], ["sqlite3", "data.sqlite"]]
    bound = {"watch": ["--count", "2"], "log": ["--seconds", "1"]}
    config = (ROOT / "docs" / "examples" / "buses.toml").read_text()
    with Simulator(["coolpro", "hub:250"], seed=5) as sim, \
            SimulatorProcess(["hub:1", "--tcp", "127.0.0.1:0"], quiet=True) as gateway:
        port = re.search(r'port = "(/dev/[^"]+)"', config)
        assert port
        config = config.replace(port[1], sim.port).replace("192.168.1.50:502", gateway.endpoint)
        (tmp_path / "buses.toml").write_text(config)
        for argv in commands:
            if argv[0] == "pymb":
                args = [sim.port if a == "/dev/ttyUSB0" else a for a in argv[1:]]
                done = run_pymb(*args, *bound.get(args[0], []), cwd=tmp_path, timeout=120)
            else:
                done = subprocess.run(argv, cwd=tmp_path, capture_output=True, text=True,
                                      timeout=60, check=False)
            assert done.returncode == 0, (argv, done.stdout, done.stderr)
            assert "Traceback" not in done.stderr
            if argv[1] != "log":
                assert done.stdout.strip(), argv
    con = sqlite3.connect(tmp_path / "plant.sqlite")
    try:
        names = {n for (n,) in con.execute("SELECT DISTINCT d.name FROM samples s "
                                           "JOIN devices d ON d.id = s.device_id")}
    finally:
        con.close()
    assert names == {"psu-a", "hub-250", "hub-1"}  # both buses of buses.toml logged
