"""A user's install path: the few Debian packages the docs give are what
``.ci/setup --user`` installs, apt waits for dpkg's lock, and pymb's own
distribution name is the only one any message or page tells anyone to
install."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from pymb.extras import DISTRIBUTION, extra_requirements, install_hint

ROOT = Path(__file__).resolve().parents[2]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]

#: How the sdist's file name begins.
SDIST = DISTRIBUTION.replace("-", "_") + "-"

#: What a user needs to build pymb and run the demo (docs/install.md).
USER_PACKAGES = {"gcc", "pkg-config", "libmodbus-dev", "python3-dev", "python3-venv", "sqlite3"}


def _setup(tmp_path: Path, *args: str) -> list[str]:
    """``.ci/setup ARGS --dry-run`` on a machine that has nothing: a PATH with
    only the two commands the script itself needs, no python3, no dpkg."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir(exist_ok=True)
    for tool in ("dirname", "id"):
        found = shutil.which(tool)
        assert found
        (bin_dir / tool).symlink_to(found)
    bash = shutil.which("bash")
    assert bash
    done = subprocess.run([bash, str(ROOT / ".ci" / "setup"), *args, "--dry-run"],
                          env={"PATH": str(bin_dir)}, capture_output=True, text=True,
                          timeout=60, check=False)
    assert done.returncode == 0, done.stderr
    return [line[2:] for line in done.stdout.splitlines() if line.startswith("+ ")]


def _installed(commands: list[str]) -> set[str]:
    (line,) = [c for c in commands if " install -y " in c]
    assert "-o DPkg::Lock::Timeout=" in line
    return set(line.split(" install -y ", 1)[1].split())


def test_setup_user_installs_only_what_the_demo_needs(tmp_path: Path) -> None:
    commands = _setup(tmp_path, "--user")
    assert _installed(commands) == USER_PACKAGES
    assert not any("--add-architecture" in c for c in commands)
    update = next(c for c in commands if c.endswith(" update"))
    assert "-o DPkg::Lock::Timeout=" in update
    assert commands[-1].endswith("pip install -q --disable-pip-version-check -e .")


def test_setup_for_ci_installs_the_rest(tmp_path: Path) -> None:
    commands = _setup(tmp_path)
    packages = _installed(commands)
    assert packages > USER_PACKAGES
    assert {"mbpoll", "mosquitto-clients", "qemu-user", "valgrind"} <= packages
    assert "protobuf-compiler" not in packages  # Sparkplug decodes through pysparkplug
    assert any(c.endswith("dpkg --add-architecture arm64") for c in commands)
    assert commands[-1].endswith("-e .[test]")


def test_setup_refuses_an_unknown_argument() -> None:
    done = subprocess.run([str(ROOT / ".ci" / "setup"), "--usr"], capture_output=True,
                          text=True, timeout=60, check=False)
    assert done.returncode == 2
    assert done.stderr == "usage: .ci/setup [--user] [--dry-run]\n"


@pytest.mark.parametrize("page", ["README.md", "docs/install.md"])
def test_the_docs_apt_line_is_what_setup_user_installs(page: str) -> None:
    lines = [line.split("sudo apt install ", 1)[1].split("#")[0].split()
             for line in (ROOT / page).read_text().splitlines() if "sudo apt install " in line]
    assert set(lines[0]) == USER_PACKAGES


def test_one_distribution_name() -> None:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert project["name"] == DISTRIBUTION
    # a hint names the extra's packages, installed by the Python that runs pymb
    assert install_hint("mqtt") == f"{sys.executable} -m pip install 'paho-mqtt<3,>=2.1'"
    def name(req: str) -> str:
        return re.split(r"[<>=!~ ]", req, maxsplit=1)[0]

    for extra in ("mqtt", "plot", "bench"):
        want = project["optional-dependencies"][extra]
        assert sorted(map(name, extra_requirements(extra))) == sorted(map(name, want)), extra
    assert set(project["optional-dependencies"]) >= {"mqtt", "plot", "bench", "test"}


def test_no_message_or_page_names_another_distribution() -> None:
    # `pip install NAME...` and `NAME[extra]` where NAME starts with pymb: only
    # pymb's own distribution (PyPI's `pymb` is somebody else's).
    pattern = re.compile(r"pip install\s+['\"]?(pymb[\w.-]*)|\b(pymb[\w.-]*)\[(\w+)\]")
    sources = [*DOCS, *sorted((ROOT / "pymb").rglob("*.py")), *sorted((ROOT / ".ci").iterdir())]
    seen = 0
    bad = []
    for path in sources:
        for n, line in enumerate(path.read_text().splitlines(), 1):
            for m in pattern.finditer(line):
                seen += 1
                name = m.group(1) or m.group(2)
                if name != DISTRIBUTION and not name.startswith(SDIST):
                    bad.append(f"{path.relative_to(ROOT)}:{n}: {line.strip()}")
    assert not bad, "\n".join(bad)
    assert seen >= 8  # the hints and the pages were read
