"""docs/c-api.md's C examples compile against the headers in csrc/ (the man
pages' examples are compiled by ``make -C csrc check-man``)."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest
from docblocks import claim

ROOT = Path(__file__).resolve().parents[2]


def c_blocks() -> list[str]:
    return [b.text for b in claim("docs/c-api.md", "c", how="compile")]


def test_the_guide_has_a_c_example() -> None:
    assert any("int main" in b and "pymb_line_new" in b for b in c_blocks())


@pytest.mark.parametrize("n", range(len(c_blocks())))
def test_every_c_example_in_the_guide_compiles(tmp_path: Path, n: int) -> None:
    if shutil.which("cc") is None or shutil.which("pkg-config") is None:
        pytest.skip("needs cc and pkg-config")
    src = tmp_path / "example.c"
    src.write_text(c_blocks()[n])
    mb = subprocess.run(["pkg-config", "--cflags", "libmodbus"], capture_output=True,
                        text=True, check=True).stdout.split()
    r = subprocess.run(["cc", "-std=c99", "-Wall", "-Wextra", "-Werror", f"-I{ROOT / 'csrc'}",
                        *mb, "-c", str(src), "-o", str(tmp_path / "example.o")],
                       capture_output=True, text=True, check=False)
    assert r.returncode == 0, r.stderr
