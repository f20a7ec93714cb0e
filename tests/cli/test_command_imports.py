"""What each command loads: a command that reads a device (read, watch, scan,
config) loads neither the logger, the store nor the fleet package, and no
layer imports one above it. Run in a fresh interpreter per command, as a user
starts it."""

from __future__ import annotations

import subprocess
import sys

import pytest
from conftest import PYMB_ENV

ABOVE_THE_DEVICES = ("pymb.logger", "pymb.store", "pymb.fleet", "pymb.bench")


def loaded(*argv: str) -> set[str]:
    """The pymb modules loaded by ``pymb ARGV`` (``--help``: it parses, then exits)."""
    code = ("import sys\nimport pymb.cli\ntry:\n    pymb.cli.main(sys.argv[1:])\n"
            "except SystemExit:\n    pass\n"
            "print('\\n'.join(m for m in sys.modules if m.startswith('pymb')), "
            "file=sys.stderr)\n")
    r = subprocess.run([sys.executable, "-c", code, *argv], env=PYMB_ENV, capture_output=True,
                       text=True, timeout=60, check=False)
    assert r.returncode == 0, r.stderr
    return set(r.stderr.split())


@pytest.mark.parametrize("command", ["read", "watch", "scan", "config"])
def test_a_command_that_reads_a_device_loads_no_logger_store_or_fleet(command: str) -> None:
    mods = loaded(command, "--help")
    assert f"pymb.commands.{command}" in mods
    assert "pymb.devices.spec" in mods  # the device syntax, from beside the devices
    assert sorted(m for m in mods if m.startswith(ABOVE_THE_DEVICES)) == []


@pytest.mark.parametrize(("module", "forbidden"), [
    ("pymb.client", ("pymb.devices", "pymb.logger", "pymb.store", "pymb.fleet",
                     "pymb.commands", "pymb.sim")),
    ("pymb.devices", ("pymb.logger", "pymb.store", "pymb.fleet", "pymb.commands", "pymb.sim")),
    ("pymb.store", ("pymb.logger", "pymb.fleet", "pymb.commands", "pymb.sim")),
    ("pymb.logger", ("pymb.fleet", "pymb.commands", "pymb.sim")),
    ("pymb.fleet", ("pymb.logger", "pymb.commands", "pymb.sim")),
])
def test_no_layer_imports_one_above_it(module: str, forbidden: tuple[str, ...]) -> None:
    code = (f"import sys\nimport {module}\n"
            "print('\\n'.join(m for m in sys.modules if m.startswith('pymb')))\n")
    r = subprocess.run([sys.executable, "-c", code], env=PYMB_ENV, capture_output=True,
                       text=True, timeout=60, check=False)
    assert r.returncode == 0, r.stderr
    assert sorted(m for m in r.stdout.split() if m.startswith(forbidden)) == []
