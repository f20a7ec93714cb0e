"""``--ascii`` (with ``--port PATH --baud N``) and ``--udp HOST:PORT`` in
``pymb read`` and ``pymb log``, and ``ascii = true`` / ``udp = "HOST:PORT"``
in the logger's TOML, against pymodbus serving ASCII on a pseudo-terminal
and UDP on 127.0.0.1 (tests/pymodbus_server.py: holding register a holds
7 * a)."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import pytest
from conftest import run_pymb
from docblocks import claim_one
from wire_peers import pymodbus_peer

from pymb.errors import InvalidArgument
from pymb.logger.config import config_from_toml

MAP = '''schema = "pymb.map/1"
[device]
id = "acme-meter"
table = "holding"
[groups]
fast = { interval = 0.2 }
[[point]]
name = "a"
address = 3
type = "u16"
group = "fast"
[[point]]
name = "b"
address = 300
type = "u16"
group = "fast"
'''


@pytest.fixture
def map_file(tmp_path: Path) -> Path:
    path = tmp_path / "pm.toml"
    path.write_text(MAP)
    return path


def where(mode: str, peer: str) -> list[str]:
    return (["--ascii", "--port", peer, "--baud", "19200"] if mode == "ascii"
            else ["--udp", f"127.0.0.1:{peer}"])


@pytest.mark.parametrize("mode", ["ascii", "udp"])
def test_read_and_log(mode: str, map_file: Path, tmp_path: Path) -> None:
    with pymodbus_peer(mode) as peer:
        done = run_pymb("read", "--map", str(map_file), "acme-meter:17", *where(mode, peer),
                        "--json")
        assert done.returncode == 0, done.stderr
        assert json.loads(done.stdout)["values"] == {"a": 21, "b": 2100}
        out = tmp_path / "log.jsonl"
        done = run_pymb("log", "--map", str(map_file), "acme-meter:17", *where(mode, peer),
                        "--format", "jsonl", "--out", str(out), "--seconds", "1.5", "--quiet")
        assert done.returncode == 0, done.stderr
        rows = [json.loads(line) for line in out.read_text().splitlines()]
        assert rows
        assert "2100" in out.read_text()
        assert "21" in out.read_text()


def test_toml_buses(map_file: Path, tmp_path: Path) -> None:
    with pymodbus_peer("ascii") as pty, pymodbus_peer("udp") as port:
        config = tmp_path / "buses.toml"
        out = tmp_path / "log.jsonl"
        config.write_text(f'''maps = ["{map_file}"]
[output]
format = "jsonl"
path = "{out}"

[[bus]]
name = "serial-ascii"
port = "{pty}"
ascii = true
baud = 19200
[[bus.device]]
type = "acme-meter"
address = 17
name = "over-ascii"

[[bus]]
name = "udp"
udp = "127.0.0.1:{port}"
[[bus.device]]
type = "acme-meter"
address = 1
name = "over-udp"
''')
        done = run_pymb("log", "--config", str(config), "--seconds", "1.5", "--quiet")
        assert done.returncode == 0, done.stderr
        text = out.read_text()
        assert "over-ascii" in text
        assert "over-udp" in text
        assert "2100" in text


def test_mistakes_are_one_line(tmp_path: Path) -> None:
    done = run_pymb("read", "coolpro", "--ascii", "--tcp", "127.0.0.1:502")
    assert done.returncode == 2
    assert "--ascii" in done.stderr
    assert "Traceback" not in done.stderr
    done = run_pymb("read", "coolpro", "--udp", "nohost")
    assert done.returncode == 2
    assert "--udp" in done.stderr
    with pytest.raises(InvalidArgument, match="ascii = true is for a serial bus"):
        config_from_toml(tomllib.loads('[[bus]]\nudp = "127.0.0.1:502"\nascii = true\n'
                                       '[[bus.device]]\ntype = "coolpro"\n'), "x.toml")
    # a bus's address is checked as the file is read: the output is never made
    config = tmp_path / "bad.toml"
    config.write_text('[output]\npath = "out.sqlite"\n[[bus]]\nudp = "mbaps://127.0.0.1:802"\n'
                      '[[bus.device]]\ntype = "coolpro"\n')
    done = run_pymb("log", "--config", str(config), "--seconds", "1", "--quiet", cwd=tmp_path)
    assert done.returncode == 2, done.stderr
    assert done.stderr == (f"pymb log: {config}: bus 'bus1': udp needs HOST:PORT, "
                           "got 'mbaps://127.0.0.1:802'\n")
    assert not (tmp_path / "out.sqlite").exists()
    with pytest.raises(InvalidArgument, match="udp needs HOST:PORT, got 'localhost'"):
        config_from_toml(tomllib.loads('[[bus]]\nudp = "localhost"\n'
                                       '[[bus.device]]\ntype = "coolpro"\n'), "x.toml")
    with pytest.raises(InvalidArgument, match="ascii is true or false"):
        config_from_toml(tomllib.loads('[[bus]]\nport = "/dev/null"\nascii = "yes"\n'
                                       '[[bus.device]]\ntype = "coolpro"\n'), "x.toml")


def test_the_docs_lines_run(map_file: Path, tmp_path: Path) -> None:
    # docs/cli.md's two lines, as shown, with meter.toml this test's map and
    # the pty and port pymodbus serves on.
    block = claim_one("docs/cli.md", "sh", how="run", contains="--ascii --port")
    lines = [line.split() for line in block.lines() if line.startswith("pymb ")]
    assert len(lines) == 2
    (tmp_path / "meter.toml").write_text(map_file.read_text())
    with pymodbus_peer("ascii") as pty, pymodbus_peer("udp") as port:
        for argv in lines:
            argv = [pty if a == "/dev/ttyUSB1" else f"127.0.0.1:{port}"
                    if a == "192.168.1.51:502" else a for a in argv[1:]]
            extra = ["--seconds", "1"] if argv[0] == "log" else []
            done = run_pymb(*argv, *extra, cwd=tmp_path)
            assert done.returncode == 0, (argv, done.stderr)
            assert "2100" in done.stdout, argv


@pytest.mark.parametrize("command", ["read", "log"])
@pytest.mark.parametrize("other", ["--tcp", "--udp"])
def test_ascii_without_port_is_refused_in_one_line(command: str, other: str) -> None:
    done = run_pymb(command, "coolpro:40", "--ascii", other, "127.0.0.1:1")
    assert done.returncode == 2
    assert done.stderr == (f"pymb {command}: --ascii is Modbus ASCII on a serial line: "
                           "give it with --port PATH\n")
