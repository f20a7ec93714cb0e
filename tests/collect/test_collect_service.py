"""contrib/pymb-collect.service: systemd accepts it (``systemd-analyze
verify``, no warnings), its command line is one ``pymb collect`` takes, with
a fixed client id (the broker keeps the session for it), and its exit-code
policy is pymb's."""

from __future__ import annotations

import configparser
from pathlib import Path

from conftest import ROOT
from unitkit import unit_of, verify_unit

from pymb.cli import EXIT_USAGE, build_parser

UNIT = ROOT / "contrib" / "pymb-collect.service"


def _service() -> configparser.SectionProxy:
    return unit_of(UNIT)["Service"]


def test_systemd_analyze_verify_accepts_the_unit(tmp_path: Path) -> None:
    verify_unit(UNIT, "collect", tmp_path)


def test_the_unit_runs_one_collector_restarted_on_failure_only() -> None:
    s = _service()
    assert s["Restart"] == "on-failure"
    assert s["RestartPreventExitStatus"] == str(EXIT_USAGE)
    assert s["User"] == "pymb-collect"
    argv = s["ExecStart"].split()[1:]
    args = build_parser("collect").parse_args(argv)
    assert args.command == "collect"
    assert args.client_id  # the same session on every start
    assert args.quiet
    assert args.out.startswith("postgresql://")
    assert ":" not in args.out.split("//")[1].split("@")[0]  # no password in the unit
