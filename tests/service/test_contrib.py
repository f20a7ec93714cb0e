"""The unit file and the example configuration in contrib/: systemd accepts
the unit (``systemd-analyze verify``, no warnings), its command line is one
pymb takes, its exit codes are pymb's, and the TOML loads with pymb's own
configuration loader."""

from __future__ import annotations

import configparser
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import ROOT

from pymb.cli import EXIT_USAGE, build_parser
from pymb.commands.logconfig import load

UNIT = ROOT / "contrib" / "pymb.service"
TOML = ROOT / "contrib" / "pymb.toml"


def _unit() -> configparser.ConfigParser:
    unit = configparser.ConfigParser(strict=False, interpolation=None)
    unit.optionxform = str  # type: ignore[assignment,method-assign]
    unit.read_string(UNIT.read_text())
    return unit


def test_systemd_analyze_verify_accepts_the_unit(tmp_path: Path) -> None:
    tool = shutil.which("systemd-analyze")
    if tool is None:
        pytest.fail("systemd-analyze is not installed: .ci/setup installs systemd")
    # ExecStart names /opt/pymb/bin/pymb, as docs/board.md installs it; verify
    # checks that the program exists, so point it at this pymb
    pymb = Path(sys.executable).parent / "pymb"
    assert pymb.exists()
    text = UNIT.read_text()
    assert "/opt/pymb/bin/pymb log " in text
    unit = tmp_path / "pymb.service"
    unit.write_text(text.replace("/opt/pymb/bin/pymb", str(pymb)))
    r = subprocess.run([tool, "verify", "--man=no", str(unit)], capture_output=True,
                       text=True, timeout=60, check=False)
    assert r.returncode == 0, r.stderr
    assert r.stderr.strip() == "", r.stderr  # unknown keys and bad values are only warnings


def test_the_unit_is_a_notify_service_restarted_on_failure_only() -> None:
    s = _unit()["Service"]
    assert s["Type"] == "notify"
    assert s["NotifyAccess"] == "main"
    assert s["User"] == "pymb"
    assert s["SupplementaryGroups"] == "dialout"
    assert s["StateDirectory"] == "pymb"
    assert s["Restart"] == "on-failure"
    assert s["RestartPreventExitStatus"] == str(EXIT_USAGE)  # configuration errors only
    assert int(s["WatchdogSec"]) > 0
    assert s["ExecReload"] == "/bin/kill -HUP $MAINPID"
    argv = s["ExecStart"].split()[1:]
    args = build_parser("log").parse_args(argv)
    assert args.command == "log"
    assert args.quiet
    assert args.config == "/etc/pymb/pymb.toml"


def test_the_example_configuration_loads() -> None:
    cfg, mqtt = load(str(TOML))
    assert cfg.format == "sqlite"
    assert cfg.path == "/var/lib/pymb/data.sqlite"  # inside the unit's StateDirectory
    assert cfg.max_bytes == 2_000_000_000
    assert cfg.max_age == 365 * 86400
    (bus,) = cfg.buses
    assert bus.port is not None
    assert bus.port.startswith("/dev/serial/by-id/")
    assert [(d.type, d.address, d.name) for d in bus.devices] == [
        ("coolpro", 40, "psu-a"), ("hub", 250, "hub-a")]
    assert mqtt is not None
    assert mqtt.node == "board-7"
