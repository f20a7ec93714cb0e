"""The shell lines of the pages for C users and maintainers (``c-core.md``,
``development.md``, ``arm.md``) name what exists: each ``make -C csrc``
line is one the Makefile accepts (``make -n``: planned, not run; the builds
themselves run in CI's ``make -C csrc check``, ``.ci/check-arm`` and
``.ci/check-c-install``), each ``.ci/`` script is there and executable, and
each pytest line names test files and markers that exist."""

from __future__ import annotations

import os
import re
import shlex
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PAGES = ["docs/c-core.md", "docs/development.md", "docs/arm.md"]


def shell_lines(page: str) -> list[str]:
    """Each command of the page's ``sh`` blocks and indented blocks, comments
    dropped and continuation lines joined."""
    text = (ROOT / page).read_text(encoding="utf-8")
    blocks = re.findall(r"^```sh\n(.*?)^```$", text, re.S | re.M)
    blocks += re.findall(r"(?:^\n)((?:^    \S.*\n)+)", text, re.M)
    lines = []
    for block in blocks:
        joined = re.sub(r"\\\n\s*", " ", block)
        for line in joined.splitlines():
            for part in re.sub(r"\s+#.*", "", line).split(";"):
                if part.strip():
                    lines.append(part.strip())
    return lines


LINES = [(page, line) for page in PAGES for line in shell_lines(page)]


def test_the_pages_have_shell_lines() -> None:
    assert {page for page, _ in LINES} == set(PAGES)
    assert sum(1 for _, line in LINES if "make -C csrc" in line) >= 8


@pytest.mark.parametrize(("page", "line"), LINES, ids=[line for _, line in LINES])
def test_a_shell_line_names_what_exists(page: str, line: str) -> None:
    words = shlex.split(line)
    env = dict(os.environ)
    while words and re.fullmatch(r"[A-Z_]+=.*", words[0]):  # VAR=value before the command
        name, _, value = words.pop(0).partition("=")
        env[name] = value
    if words[:1] == ["sudo"]:
        words.pop(0)
    if words[:3] == ["make", "-C", "csrc"]:
        r = subprocess.run(["make", "-n", *words[1:]], cwd=ROOT, env=env, capture_output=True,
                           text=True, timeout=60, check=False)
        assert r.returncode == 0, f"{page}: {line}\n{r.stderr}"
    elif words[0].startswith(".ci/"):
        script = ROOT / words[0]
        assert script.is_file(), f"{page}: {line}"
        assert os.access(script, os.X_OK), f"{page}: {line}"
    elif words[:3] == [".venv/bin/python", "-m", "pytest"]:
        args = words[3:]
        for i, a in enumerate(args):
            if a == "-m":
                marker = args[i + 1]
                assert marker in (ROOT / "pyproject.toml").read_text(), f"{page}: {line}"
            elif a.startswith("tests/"):
                assert (ROOT / a.split("::")[0]).is_file(), f"{page}: {line}"
    elif words[0] == "./csrc/build/hub_read":
        assert "$(B)/hub_read" in (ROOT / "csrc" / "Makefile").read_text()  # built by make
    elif words[0] == "cc":
        assert "$(B)/pymb.pc" in (ROOT / "csrc" / "Makefile").read_text()  # make writes it
    else:
        pytest.fail(f"{page}: a shell line this test does not know how to check: {line}")
