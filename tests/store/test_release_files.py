"""Databases written by the release before every device became a map
(pymb log against the simulator: two hubs, one of 6 channels with mixed
humidity units, one of 100; a CoolPro; a CoolPro that never answered; one
file with every sample, one with --on-change) are read exactly as that
release read them: every export layout, the reader's samples, the MQTT
messages of both profiles, series and the summary, byte for byte
(tests/store/release/make.py made them; they are kept as SQL text and
made into files here)."""

from __future__ import annotations

import difflib
import gzip
from pathlib import Path

import pytest
from conftest import run_pymb
from release_outputs import DATABASES, OUTPUTS, outputs, restore

RELEASE = Path(__file__).resolve().parent / "release"

def _expected(name: str) -> str:
    return gzip.decompress((RELEASE / f"{name}.gz").read_bytes()).decode()


def _same(name: str, want: str, got: str) -> None:
    if got != want:
        diff = "".join(list(difflib.unified_diff(
            want.splitlines(True), got.splitlines(True), "release", "now", n=0))[:40])
        pytest.fail(f"{name} differs from what the release read:\n{diff}")


def test_the_release_files_read_as_the_release_read_them(tmp_path: Path) -> None:
    for db in DATABASES:
        restore(RELEASE / f"{Path(db).stem}.sql.gz", tmp_path / db)
    got = outputs(tmp_path)
    assert sorted(got) == sorted(OUTPUTS)
    for name in OUTPUTS:
        _same(name, _expected(name), got[name])


def test_pymb_export_writes_the_release_csv(tmp_path: Path) -> None:
    for db in DATABASES:
        restore(RELEASE / f"{Path(db).stem}.sql.gz", tmp_path / db)
        r = run_pymb("export", str(tmp_path / db), "--csv", "-", "--events", timeout=120)
        assert r.returncode == 0, r.stderr
        # the rows after export_csv's count; the pipe's text mode reads CR LF as LF
        want = _expected(f"{db}.long.csv").split("\n", 1)[1].replace("\r\n", "\n")
        _same(db, want, r.stdout)
