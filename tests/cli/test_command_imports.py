"""What each command loads: a command that reads a device (read, watch, scan,
config) loads neither the logger, the store nor the fleet package, and no
layer imports one above it. Run in a fresh interpreter per command, as a user
starts it."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import PYMB_ENV

import pymb

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
    ("pymb.sim", ("pymb.logger", "pymb.store", "pymb.fleet", "pymb.commands", "pymb.bench")),
])
def test_no_layer_imports_one_above_it(module: str, forbidden: tuple[str, ...]) -> None:
    code = (f"import sys\nimport {module}\n"
            "print('\\n'.join(m for m in sys.modules if m.startswith('pymb')))\n")
    r = subprocess.run([sys.executable, "-c", code], env=PYMB_ENV, capture_output=True,
                       text=True, timeout=60, check=False)
    assert r.returncode == 0, r.stderr
    assert sorted(m for m in r.stdout.split() if m.startswith(forbidden)) == []


#: Function-level imports of pymb modules that are allowed, by file (a prefix
#: ends in "/"), each with its reason. Anything else is a function-level import
#: that dodges an import cycle: restructure so the arrows run one way instead.
LAZY_PYMB_IMPORTS = {
    "pymb/bench/": "each bench section and worker loads only the stack it measures "
                   "(and the contenders' import time stays out of the parent)",
}


def function_level_pymb_imports(root: Path = Path(pymb.__file__).parent) -> list[str]:
    """``path:line module`` of each import of a pymb module inside a function."""
    found = []
    for path in sorted(root.rglob("*.py")):
        rel = path.relative_to(root.parent).as_posix()
        for fn in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if not isinstance(fn, ast.FunctionDef | ast.AsyncFunctionDef):
                continue
            for node in ast.walk(fn):
                if isinstance(node, ast.ImportFrom):
                    names = [node.module or ""] if node.level == 0 else ["pymb (relative)"]
                elif isinstance(node, ast.Import):
                    names = [a.name for a in node.names]
                else:
                    continue
                found += [f"{rel}:{node.lineno} {n}" for n in names
                          if n == "pymb" or n.startswith(("pymb.", "pymb ("))]
    return found


def test_no_function_level_import_of_a_pymb_module_without_a_reason() -> None:
    found = function_level_pymb_imports()
    assert any(f.startswith("pymb/bench/") for f in found)  # the scan sees them
    assert [f for f in found if not f.startswith(tuple(LAZY_PYMB_IMPORTS))] == []


def test_the_scan_sees_an_import_in_a_method_and_not_at_the_top(tmp_path: Path) -> None:
    (tmp_path / "pymb").mkdir()
    (tmp_path / "pymb" / "m.py").write_text(
        "import pymb.errors\nclass A:\n    def f(self):\n        from pymb.maps import codec\n"
        "        import paho.mqtt.client\n        from . import x\n", encoding="utf-8")
    assert function_level_pymb_imports(tmp_path / "pymb") == [
        "pymb/m.py:4 pymb.maps", "pymb/m.py:6 pymb (relative)"]
