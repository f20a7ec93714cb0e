"""docs/cli.md: ``--address``, ``--channels`` and ``--humidity-unit`` are
aliases of a DEVICE's own spelling in ``read``, ``watch`` and ``log`` (``log``
for a single DEVICE), ``config`` takes ``--address``; a value given both ways
must agree. Against the simulator, through the command as a user runs it."""

from __future__ import annotations

import json
import sqlite3
import subprocess
from pathlib import Path

from clikit import no_traceback
from conftest import run_pymb

from pymb.sim import Simulator


def _refused(r: subprocess.CompletedProcess[str], text: str) -> None:
    """Exit 2 and one line saying ``text``."""
    no_traceback(r)
    assert r.returncode == 2, r.stderr
    err = r.stderr.strip()
    assert text in err, err
    assert len(err.splitlines()) == 1, err


def test_log_takes_the_aliases_for_its_one_device(sim3: Simulator, tmp_path: Path) -> None:
    db = tmp_path / "aliases.sqlite"
    r = run_pymb("log", "hub", "--address", "7", "--channels", "50", "--humidity-unit", "1",
                 "--port", sim3.port, "--seconds", "1.5", "--out", str(db), "--quiet")
    no_traceback(r)
    assert r.returncode == 0, r.stderr
    with sqlite3.connect(db) as con:
        assert con.execute("SELECT name, channels, humidity_units FROM devices").fetchall() \
            == [("hub-7", 50, "1")]
        assert con.execute("SELECT COUNT(*) FROM samples").fetchone()[0] > 0


def test_log_refuses_aliases_that_disagree_or_name_no_one_device(sim3: Simulator,
                                                                tmp_path: Path) -> None:
    out = str(tmp_path / "x.sqlite")
    common = ["--port", sim3.port, "--seconds", "1", "--out", out]
    _refused(run_pymb("log", "hub:7,channels=50", "--channels", "100", *common),
             "'hub:7,channels=50' gives channels 50 and --channels 100: give it once")
    _refused(run_pymb("log", "hub:7", "--address", "8", *common),
             "gives address 7 and --address 8: give it once")
    _refused(run_pymb("log", "coolpro", "--channels", "50", *common), "--channels is for a hub")
    _refused(run_pymb("log", "coolpro", "hub:7", "--channels", "50", *common),
             "--channels is an alias for one device's own option")
    _refused(run_pymb("log", "coolpro", "--device", "hub:7", "--address", "40", *common),
             "--address is an alias for one device's own option")
    cfg = tmp_path / "bus.toml"
    cfg.write_text(f'[output]\npath = "{out}"\n[[bus]]\nport = "{sim3.port}"\n'
                   '[[bus.device]]\ntype = "hub"\naddress = 7\n')
    _refused(run_pymb("log", "--config", str(cfg), "--channels", "50", "--seconds", "1"),
             "with --config, give --channels's value in the file")
    assert not Path(out).exists()


def test_read_and_watch_take_the_aliases(sim3: Simulator) -> None:
    r = run_pymb("read", "hub", "--address", "7", "--channels", "50", "--humidity-unit", "1",
                 "--port", sim3.port, "--json")
    no_traceback(r)
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    assert doc["address"] == 7
    assert len(doc["values"]["temperature_c"]) == 50
    r = run_pymb("watch", "hub", "--address", "7", "--channels", "50", "--port", sim3.port,
                 "--count", "1", "--json")
    no_traceback(r)
    assert r.returncode == 0, r.stderr
    _refused(run_pymb("watch", "hub:7", "--address", "250", "--port", sim3.port,
                      "--count", "1"), "give it once")


def test_config_takes_the_address_alias(sim3: Simulator) -> None:
    r = run_pymb("config", "coolpro", "--address", "40", "--port", sim3.port)
    no_traceback(r)
    assert r.returncode == 0, r.stderr
    assert "CoolPro at 40" in r.stdout
