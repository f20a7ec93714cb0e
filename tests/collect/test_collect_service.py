"""contrib/pymb-collect.service: systemd accepts it (``systemd-analyze
verify``, no warnings), its command line is one ``pymb collect`` takes, with
a fixed client id (the broker keeps the session for it), and its exit-code
policy is pymb's."""

from __future__ import annotations

import configparser
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import ROOT

from pymb.cli import EXIT_USAGE, build_parser

UNIT = ROOT / "contrib" / "pymb-collect.service"


def _service() -> configparser.SectionProxy:
    unit = configparser.ConfigParser(strict=False, interpolation=None)
    unit.optionxform = str  # type: ignore[assignment,method-assign]
    unit.read_string(UNIT.read_text())
    return unit["Service"]


def test_systemd_analyze_verify_accepts_the_unit(tmp_path: Path) -> None:
    tool = shutil.which("systemd-analyze")
    if tool is None:
        pytest.fail("systemd-analyze is not installed: .ci/setup installs systemd")
    pymb = Path(sys.executable).parent / "pymb"
    assert pymb.exists()
    text = UNIT.read_text()
    assert "/opt/pymb/bin/pymb collect " in text
    unit = tmp_path / "pymb-collect.service"
    unit.write_text(text.replace("/opt/pymb/bin/pymb", str(pymb)))
    r = subprocess.run([tool, "verify", "--man=no", str(unit)], capture_output=True,
                       text=True, timeout=60, check=False)
    assert r.returncode == 0, r.stderr
    assert r.stderr.strip() == "", r.stderr


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
