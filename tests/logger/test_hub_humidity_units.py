"""A hub's humidity unit given per channel in the TOML (``humidity_unit =
[1, 0.1, ...]``, docs/cli.md): the hub is its shipped map with options, and
the per-channel list reaches the stored device row and the decoded values."""

from __future__ import annotations

import sqlite3
from pathlib import Path

from clikit import no_traceback
from conftest import run_pymb

from pymb.logger import load_config
from pymb.sim import Simulator


def _toml(port: str, units: str, out: Path) -> str:
    return (f'[output]\npath = "{out}"\n[[bus]]\nname = "b"\nport = "{port}"\n'
            f'[[bus.device]]\ntype = "hub"\naddress = 1\nchannels = 3\n'
            f'humidity_unit = {units}\n')


def test_a_per_channel_list_configures_the_map_with_its_most_common_unit(
        tmp_path: Path) -> None:
    cfg = tmp_path / "hub.toml"
    cfg.write_text(_toml("/dev/null", "[1, 0.1, 1]", tmp_path / "x.sqlite"))
    (hub,) = load_config(cfg).buses[0].devices
    assert hub.polls == [("sweep", None)]  # at the bus's interval
    assert hub.option("humidity_unit") == (1, 0.1, 1)
    assert hub.map.options == {"channels": 3, "humidity_unit": 1}
    assert hub.spec == "hub:1,channels=3"


def test_logged_hub_keeps_each_channels_unit(tmp_path: Path) -> None:
    db = tmp_path / "units.sqlite"
    cfg = tmp_path / "hub.toml"
    with Simulator(["hub:1"], seed=4) as sim:
        cfg.write_text(_toml(sim.port, "[1, 0.1, 1]", db))
        r = run_pymb("log", "--config", str(cfg), "--seconds", "1", "--quiet")
    no_traceback(r)
    assert r.returncode == 0, r.stderr
    with sqlite3.connect(db) as con:
        assert con.execute("SELECT channels, humidity_units FROM devices").fetchall() == [
            (3, "1,0.1,1")]
        assert con.execute("SELECT COUNT(*) FROM samples").fetchone()[0] > 0


def test_a_list_of_the_wrong_length_is_one_line(tmp_path: Path) -> None:
    cfg = tmp_path / "hub.toml"
    cfg.write_text(_toml("/dev/null", "[1, 0.1]", tmp_path / "x.sqlite"))
    r = run_pymb("log", "--config", str(cfg), "--seconds", "1")
    no_traceback(r)
    assert r.returncode == 2, r.stderr
    assert "2 humidity_unit values given for 3 channels" in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert not (tmp_path / "x.sqlite").exists()
