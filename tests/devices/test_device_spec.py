"""The one device syntax, ``TYPE[:ADDRESS][,key=value...]``: the commands that
read and log a device and the simulator that serves one read it alike."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import pytest
from conftest import run_pymb

import pymb
from pymb.devices import HUB_FIRMWARE_PROFILES
from pymb.devices.identify import client_asker, identify
from pymb.devices.spec import split_spec
from pymb.errors import InvalidArgument
from pymb.logger import parse_device
from pymb.sim import Simulator
from pymb.sim.simulator import make_device


@pytest.mark.parametrize(("text", "address"), [
    ("40", 40), ("040", 40), ("0x28", 40), ("0X28", 40), ("0o50", 40), ("0b101000", 40),
])
def test_an_address_is_read_alike_to_log_and_to_simulate(text: str, address: int) -> None:
    assert parse_device(f"coolpro:{text}").address == address
    assert make_device(f"coolpro:{text}").address == address


@pytest.mark.parametrize("text", ["x1", "4o", "0x", "", "forty"])
def test_a_bad_address_is_refused_alike(text: str) -> None:
    with pytest.raises(InvalidArgument, match="the address must be a whole number"):
        parse_device(f"coolpro:{text}")
    if text:  # "coolpro:" serves the default address
        with pytest.raises(InvalidArgument, match="the address must be a whole number"):
            make_device(f"coolpro:{text}")


def test_the_grammar_splits_type_address_and_options() -> None:
    assert split_spec(" Hub:0x10 , channels=50,humidity-unit = 1,name") == (
        "hub", "0x10", [("channels", True, "50"), ("humidity_unit", True, "1"),
                        ("name", False, "")])
    assert split_spec("coolpro") == ("coolpro", None, [])


def test_pymb_log_takes_a_hex_address_as_simulate_serves_it(tmp_path: Path) -> None:
    db = tmp_path / "hex.sqlite"
    with Simulator(["coolpro:0x28"], seed=1) as sim:
        r = run_pymb("log", "coolpro:0x28", "--port", sim.port, "--seconds", "1",
                     "--out", str(db), "--quiet")
    assert r.returncode == 0, r.stderr
    with sqlite3.connect(db) as con:
        (address,) = con.execute("SELECT address FROM devices").fetchone()
        (n,) = con.execute("SELECT COUNT(*) FROM samples").fetchone()
    assert address == 40
    assert n > 0


@pytest.mark.parametrize("firmware", sorted(HUB_FIRMWARE_PROFILES))
def test_identification_names_each_firmware_profile(firmware: str) -> None:
    """What answers is named from the one table of which firmware has which
    block (HUB_FIRMWARE_PROFILES), as the simulator serves it."""
    channels, blocks = HUB_FIRMWARE_PROFILES[firmware]
    with Simulator([f"hub:7,firmware={firmware}"], seed=1) as sim, \
            pymb.RtuClient(sim.port, 9600, timeout=1.0) as c:
        found = identify(client_asker(c), 7)
    assert found is not None
    assert (found.device, found.channels) == ("hub", channels)
    assert set(found.blocks) == set(blocks)
    assert f"V{firmware}" in found.detail
