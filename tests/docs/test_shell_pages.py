"""The install, build and maintenance lines of the docs name what exists, and
run where running them costs nothing: each ``make -C csrc`` line is one the
Makefile accepts (``make -n``: planned, not run; the builds themselves run in
CI's ``make -C csrc check``, ``.ci/check-arm`` and ``.ci/check-c-install``);
each ``.ci/`` script is there and executable, and ``.ci/setup`` lines run
with ``--dry-run``; each pytest line names test files and markers that
exist; ``sudo apt install`` lines name packages ``.ci/setup`` installs;
``python3 -m venv`` makes a venv; ``pip install`` names this project, its
extras and its sdist; a ``pymb`` line is accepted by the command's parser;
``man`` names a page of csrc/man."""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
from docblocks import Block, claim

import pymb
from pymb.cli import build_parser
from pymb.extras import DISTRIBUTION

ROOT = Path(__file__).resolve().parents[2]

BLOCKS: list[Block] = [
    *claim("docs/c-core.md", "sh", how="check"),
    *claim("docs/development.md", "sh", how="check"),
    *claim("docs/arm.md", "sh", how="check"),
    *claim("README.md", "sh", how="check", contains=".ci/"),
    *claim("README.md", "sh", how="check", contains="apt install"),
    *claim("README.md", "sh", how="check", contains="make -C csrc"),
    *claim("docs/install.md", "sh", how="check"),
    *claim("docs/c-api.md", "sh", how="check"),
    *claim("docs/board.md", "sh", how="check", contains="apt install"),
    *claim("docs/benchmarks.md", "sh", how="check", contains="pymb bench"),
]


def shell_lines(block: Block) -> list[str]:
    """Each command of a block, comments dropped, continuation lines joined,
    ``&&`` and ``;`` lists split."""
    joined = re.sub(r"\\\n\s*", " ", block.text)
    lines = []
    for line in joined.splitlines():
        for part in re.split(r"&&|;", re.sub(r"(^|\s)#.*", "", line)):
            if part.strip():
                lines.append(part.strip().removesuffix("&").strip())
    return lines


LINES = [(b, line) for b in BLOCKS for line in shell_lines(b)]


def _setup_installs(package: str) -> bool:
    """Whether ``.ci/setup`` installs ``package`` where it is missing
    (``need+=(...)``: what it installs depends on what the machine has)."""
    text = (ROOT / ".ci" / "setup").read_text()
    return any(package in m.split() for m in re.findall(r"need\+=\(([^)]*)\)", text))


def test_the_pages_have_shell_lines() -> None:
    assert {b.page for b in BLOCKS} >= {"docs/c-core.md", "docs/development.md", "docs/arm.md",
                                         "README.md", "docs/install.md", "docs/board.md"}
    assert sum(1 for _, line in LINES if "make -C csrc" in line) >= 8


def _pip(words: list[str], where: str) -> None:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    extras = set(project["optional-dependencies"])
    version = pymb.__version__
    specs = [w for w in words[2:] if not w.startswith("-")]
    assert specs, where
    for spec in specs:
        name, _, extra = spec.partition("[")
        for e in extra.rstrip("]").split(",") if extra else []:
            assert e in extras, f"{where}: no extra {e!r}"
        if name == ".":
            assert (ROOT / "pyproject.toml").is_file()
        elif name.endswith(".tar.gz"):
            assert Path(name).name == f"{DISTRIBUTION.replace('-', '_')}-{version}.tar.gz" or \
                "X.Y.Z" in name, f"{where}: {name} is not this version's sdist"
        else:
            assert name == DISTRIBUTION, f"{where}: {name} is not pymb's distribution"


@pytest.mark.parametrize(("block", "line"), LINES, ids=[line for _, line in LINES])
def test_a_shell_line_names_what_exists(block: Block, line: str, tmp_path: Path) -> None:
    where = f"{block.where}: {line}"
    words = shlex.split(line)
    env = dict(os.environ)
    while words and re.fullmatch(r"[A-Z_]+=.*", words[0]):  # VAR=value before the command
        name, _, value = words.pop(0).partition("=")
        env[name] = value
    if words[:1] == ["sudo"]:
        words.pop(0)
    if words[0].startswith("$("):
        pytest.fail(f"{where}: a substitution this test cannot check")
    if words[:3] == ["make", "-C", "csrc"]:
        r = subprocess.run(["make", "-n", *words[1:]], cwd=ROOT, env=env, capture_output=True,
                           text=True, timeout=60, check=False)
        assert r.returncode == 0, f"{where}\n{r.stderr}"
    elif words[0] == ".ci/setup":
        r = subprocess.run(["bash", str(ROOT / words[0]), *words[1:], "--dry-run"],
                           capture_output=True, text=True, timeout=60, check=False)
        assert r.returncode == 0, f"{where}\n{r.stderr}"
    elif words[0].startswith(".ci/"):
        script = ROOT / words[0]
        assert script.is_file(), where
        assert os.access(script, os.X_OK), where
    elif words[:3] == [".venv/bin/python", "-m", "pytest"]:
        args = words[3:]
        for i, a in enumerate(args):
            if a == "-m":
                marker = args[i + 1]
                assert marker in (ROOT / "pyproject.toml").read_text(), where
            elif a.startswith("tests/"):
                assert (ROOT / a.split("::")[0]).is_file(), where
    elif words[0] in ("./csrc/build/hub_read", "./csrc/build/sweep_compare"):
        assert f"$(B)/{words[0].rsplit('/', 1)[1]}" in (ROOT / "csrc" / "Makefile").read_text()
    elif words[0] == "cc":
        assert "$(B)/pymb.pc" in (ROOT / "csrc" / "Makefile").read_text()  # make writes it
        assert "pkg-config --cflags --libs pymb" in line, where
    elif words[0] == "man":
        assert list((ROOT / "csrc" / "man").glob(f"{words[1]}.[37]")), where
    elif words[:2] in (["apt", "install"], ["apt-get", "install"]):
        for package in (w for w in words[2:] if not w.startswith("-")):
            assert _setup_installs(package), f"{where}: .ci/setup never installs {package}"
    elif words[:3] == ["python3", "-m", "venv"]:
        # made for real (without pip: that would need the network)
        venv = tmp_path / words[3].lstrip("/")  # /opt/pymb too: under tmp_path
        r = subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)],
                           capture_output=True, text=True, timeout=120, check=False)
        assert r.returncode == 0, f"{where}\n{r.stderr}"
        assert (venv / "bin" / "python").exists()
    elif words[0].endswith("/pip") or words[0] == "pip":
        assert words[1] == "install", where
        _pip(words, where)
    elif words[0] in ("pymb", ".venv/bin/pymb"):
        try:
            build_parser(words[1]).parse_args(words[1:])
        except SystemExit as e:
            raise AssertionError(f"{where}: refused by pymb's parser") from e
    else:
        pytest.fail(f"{where}: a shell line this test does not know how to check")
