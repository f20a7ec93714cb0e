"""A device's text on the terminal: ``pymb read`` and ``pymb write`` show a
string register's control characters (a terminal's escape sequences) as
escapes, never raw, so what a device holds cannot move the cursor, clear
the screen or retitle the window; ``--json`` keeps the text as it came."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import run_pymb
from peers import TcpPeer

MAP = """schema = "pymb.map/1"

[device]
id = "texty"
default_address = 1
table = "holding"

[[point]]
name = "label"
address = 100
type = "string"
count = 8
access = "rw"
"""

HOSTILE = "A\\x1b]0;pwned\\x07\\x1b[2J"  # a window title and a screen clear, as escapes
RAW = "A\x1b]0;pwned\x07\x1b[2J"


@pytest.fixture
def peer() -> Iterator[TcpPeer]:
    with TcpPeer() as p:
        data = RAW.encode().ljust(16, b"\0")
        p.memory.holding[100:108] = [data[i] << 8 | data[i + 1] for i in range(0, 16, 2)]
        yield p


@pytest.fixture
def map_file(tmp_path: Path) -> str:
    path = tmp_path / "texty.toml"
    path.write_text(MAP)
    return str(path)


def test_read_shows_control_characters_as_escapes(peer: TcpPeer, map_file: str) -> None:
    host, port = peer.address
    r = run_pymb("read", "--map", map_file, "texty:1", "--tcp", f"{host}:{port}")
    assert r.returncode == 0, r.stderr
    assert "\x1b" not in r.stdout
    assert "\x07" not in r.stdout
    assert r.stdout == f"label  {HOSTILE}\n"
    r = run_pymb("read", "--map", map_file, "texty:1", "--tcp", f"{host}:{port}", "--json")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["values"]["label"] == RAW


def test_write_shows_the_devices_text_before_as_escapes(peer: TcpPeer, map_file: str) -> None:
    host, port = peer.address
    r = run_pymb("write", "--map", map_file, "texty:1", "label=OK", "--tcp", f"{host}:{port}")
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines() == [f"label: {HOSTILE} -> OK"]
