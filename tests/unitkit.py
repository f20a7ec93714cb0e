"""The systemd units in contrib/, as the tests check them: the unit read as
systemd reads it, and ``systemd-analyze verify`` run on it with its
``ExecStart`` pointed at this pymb."""

from __future__ import annotations

import configparser
import shutil
import subprocess
import sys
from pathlib import Path

import pytest


def unit_of(path: Path) -> configparser.ConfigParser:
    """The unit file's sections and keys (keys as written, no interpolation)."""
    unit = configparser.ConfigParser(strict=False, interpolation=None)
    unit.optionxform = str  # type: ignore[assignment,method-assign]
    unit.read_string(path.read_text())
    return unit


def verify_unit(path: Path, command: str, tmp_path: Path) -> None:
    """``systemd-analyze verify`` accepts the unit with no warning. Its
    ``ExecStart`` names /opt/pymb/bin/pymb COMMAND, as docs/board.md installs
    pymb; verify checks that the program exists, so it is pointed at this one."""
    tool = shutil.which("systemd-analyze")
    if tool is None:
        pytest.fail("systemd-analyze is not installed: .ci/setup installs systemd")
    pymb = Path(sys.executable).parent / "pymb"
    assert pymb.exists()
    text = path.read_text()
    assert f"/opt/pymb/bin/pymb {command} " in text
    unit = tmp_path / path.name
    unit.write_text(text.replace("/opt/pymb/bin/pymb", str(pymb)))
    r = subprocess.run([tool, "verify", "--man=no", str(unit)], capture_output=True,
                       text=True, timeout=60, check=False)
    assert r.returncode == 0, r.stderr
    assert r.stderr.strip() == "", r.stderr  # unknown keys and bad values are only warnings
