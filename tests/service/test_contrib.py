"""The unit file and the example configuration in contrib/: systemd accepts
the unit (``systemd-analyze verify``, no warnings), its command line is one
pymb takes, its exit codes are pymb's, and the TOML loads with pymb's own
configuration loader."""

from __future__ import annotations

import configparser
from pathlib import Path

from conftest import ROOT
from unitkit import unit_of, verify_unit

from pymb.cli import EXIT_USAGE, build_parser
from pymb.commands.logconfig import load

UNIT = ROOT / "contrib" / "pymb.service"
TOML = ROOT / "contrib" / "pymb.toml"


def _unit() -> configparser.ConfigParser:
    return unit_of(UNIT)


def test_systemd_analyze_verify_accepts_the_unit(tmp_path: Path) -> None:
    verify_unit(UNIT, "log", tmp_path)


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
