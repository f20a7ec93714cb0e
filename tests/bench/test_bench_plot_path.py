"""``pymb bench --plot FILE``: a path the bars cannot go to is refused in one
line before anything is measured, and a file pymb did not draw is never
overwritten."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
from clikit import digest, no_traceback
from conftest import PYMB, PYMB_ENV

QUICK = ["bench", "--quick", "--only", "pymb", "-q"]


def _bench(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*PYMB, *QUICK, *args], capture_output=True, text=True, timeout=300,
                          env=PYMB_ENV)


@pytest.mark.parametrize(("name", "sections", "said"), [
    ("bench.csv", "micro", "must end in .png or .svg"),
    ("bench", "micro", "must end in .png or .svg"),
    ("bench.png", "plan", "--plot draws the sweep and micro sections"),
])
def test_a_plot_that_cannot_be_drawn_is_refused_before_measuring(
        tmp_path: Path, name: str, sections: str, said: str) -> None:
    out = tmp_path / name
    r = _bench("--sections", sections, "--plot", str(out))
    no_traceback(r)
    assert r.returncode == 2, r.stderr
    assert said in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert r.stdout == ""  # refused before anything was measured
    assert not out.exists()


def test_an_image_pymb_did_not_draw_is_kept(tmp_path: Path) -> None:
    photo = tmp_path / "photo.png"
    photo.write_bytes(b"\x89PNG\r\n\x1a\n not pymb's")
    before = digest(photo)
    r = _bench("--sections", "micro", "--plot", str(photo))
    no_traceback(r)
    assert r.returncode == 2, r.stderr
    assert "exists and is not an image pymb bench drew" in r.stderr
    assert r.stdout == ""
    assert digest(photo) == before


def test_its_own_image_is_drawn_again(tmp_path: Path) -> None:
    png = tmp_path / "bench.png"
    for _ in range(2):  # the second run replaces what the first drew
        r = _bench("--sections", "micro", "--plot", str(png))
        assert r.returncode == 0, r.stderr
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    svg = tmp_path / "bench.svg"
    assert _bench("--sections", "micro", "--plot", str(svg)).returncode == 0
    assert svg.read_text(encoding="utf-8").lstrip().startswith("<?xml")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bench.png", "bench.svg"]
