"""pymb installed with ``pip install .`` and run inside the clone it came from.

docs/install.md's "From a clone" runs ``.venv/bin/pymb demo`` there, in a
folder whose ``pymb/`` is the source tree without its built extension. The
installed command must not pick that tree up, in itself or in the children it
starts (the demo's simulators), and ``python -m pymb``, which Python points
at the folder's ``pymb/`` first, says what happened in one line.

A venv of its own stands for the installed copy: its site-packages holds this
pymb (with the extension built) and cffi, and no editable-install finder,
which would find pymb whatever the folder.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest
from conftest import ROOT

import pymb


@pytest.fixture
def installed(tmp_path: Path) -> tuple[Path, Path]:
    """(python of a venv where pymb is installed, the ``pymb`` script)."""
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True,
                   timeout=120)
    python = venv / "bin" / "python"
    site = Path(subprocess.run(
        [str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        check=True, capture_output=True, text=True, timeout=60).stdout.strip())
    here = Path(sysconfig.get_paths()["purelib"])
    (site / "pymb").symlink_to(Path(pymb.__file__).parent)
    (site / "_pymb_command.py").symlink_to(ROOT / "_pymb_command.py")
    for entry in here.iterdir():
        if entry.name.startswith(("cffi", "_cffi_backend", "pycparser")):
            (site / entry.name).symlink_to(entry)
    script = venv / "bin" / "pymb"
    # what pip writes for the console script pymb = "_pymb_command:main"
    script.write_text(f"#!{python}\nimport sys\nfrom _pymb_command import main\n"
                      "sys.exit(main())\n")
    script.chmod(0o755)
    return python, script


@pytest.fixture
def clone(tmp_path: Path) -> Path:
    """A clone's top folder: the source tree of pymb, no extension built."""
    top = tmp_path / "clone"
    shutil.copytree(ROOT / "pymb", top / "pymb",
                    ignore=shutil.ignore_patterns("*.so", "__pycache__"))
    shutil.copy(ROOT / "_pymb_command.py", top)
    return top


def test_demo_runs_inside_the_clone(installed: tuple[Path, Path], clone: Path) -> None:
    python, script = installed
    out = subprocess.run([str(python), str(script), "demo", "--seconds", "1"], cwd=clone,
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "Traceback" not in out.stderr
    assert "pymb demo:" in out.stdout
    assert "telemetry reads" in out.stdout


def test_python_m_pymb_inside_the_clone_says_why(installed: tuple[Path, Path],
                                                  clone: Path) -> None:
    python, _ = installed
    out = subprocess.run([str(python), "-m", "pymb", "--version"], cwd=clone,
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 2, out.stderr
    assert "Traceback" not in out.stderr, out.stderr
    [line] = out.stderr.strip().splitlines()
    assert f"{clone / 'pymb'} is pymb's source tree" in line, out.stderr
    assert "pip install -e ." in line
    # imported by a program of the user's, it stays an ImportError to catch
    imported = subprocess.run([str(python), "-c", "import pymb"], cwd=clone,
                              capture_output=True, text=True, timeout=60)
    assert imported.returncode == 1
    assert imported.stderr.strip().splitlines()[-1].startswith("ImportError: pymb: ")
    # outside the clone the same venv runs its pymb
    elsewhere = subprocess.run([str(python), "-m", "pymb", "--version"], cwd=clone.parent,
                               capture_output=True, text=True, timeout=60)
    assert elsewhere.returncode == 0, elsewhere.stderr
    assert elsewhere.stdout.startswith("pymb ")
