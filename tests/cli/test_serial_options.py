"""``--baud``/``--parity`` are a serial line's (``--port PATH``): with any
other transport every command refuses them in one line, exit 2, naming the
option and the transport, before anything is opened; with ``--port`` they
are taken as before."""

from __future__ import annotations

import pytest
from conftest import run_pymb

from pymb.sim import SimulatorProcess

#: each family of commands that talks to a device, on a transport given last
COMMANDS = [
    ["read", "coolpro:40"],
    ["write", "coolpro:40", "reset=43605"],
    ["scan"],
    ["config", "coolpro:40", "--set-address", "41"],
    ["map", "probe", "1", "holding:0:2"],
    ["serve", "--listen", "127.0.0.1:0"],
    ["log", "coolpro:40", "--out", "-", "--format", "jsonl"],
]

TRANSPORTS = [
    (["--tcp", "127.0.0.1:1"], "--tcp 127.0.0.1:1"),
    (["--tcp", "mbaps://127.0.0.1:1"], "--tcp mbaps://127.0.0.1:1"),
    (["--udp", "127.0.0.1:1"], "--udp 127.0.0.1:1"),
    (["--rtu-over-tcp", "127.0.0.1:1"], "--rtu-over-tcp 127.0.0.1:1"),
]


@pytest.mark.parametrize("command", COMMANDS, ids=lambda c: " ".join(c[:2]))
@pytest.mark.parametrize(("option", "value"), [("--baud", "19200"), ("--parity", "E")])
def test_a_serial_option_without_a_serial_line_is_refused_in_one_line(
        command: list[str], option: str, value: str) -> None:
    for where, named in TRANSPORTS:
        r = run_pymb(*command, *where, option, value, timeout=60)
        assert r.returncode == 2, (where, r.stderr)
        assert r.stdout == ""
        lines = r.stderr.splitlines()
        assert len(lines) == 1, r.stderr
        assert lines[0].endswith(f"{option} is for a serial line (--port PATH), not {named}"), \
            lines[0]


def test_log_with_a_config_file_names_its_bus_table(tmp_path: object) -> None:
    r = run_pymb("log", "--config", "nowhere.toml", "--baud", "19200", timeout=60)
    assert r.returncode == 2, r.stderr
    assert r.stderr.strip().endswith("with --config, give --baud's value in the file's "
                                     "[[bus]] table"), r.stderr


def test_a_command_that_opens_its_transport_twice_is_not_refused() -> None:
    """The check runs once per command line: ``pymb config`` opens a second
    client to verify the device after its reset (and ``pymb log`` a SunSpec
    device's for discovery), which must not find the defaults filled in by
    the first one and refuse them as given."""
    with SimulatorProcess(["coolpro:40", "--tcp", "127.0.0.1:0"], quiet=True) as sim:
        r = run_pymb("config", "coolpro:40", "--set-address", "41", "--reset", "--yes",
                     "--tcp", sim.endpoint, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "verified: the CoolPro answers at address 41" in r.stdout
