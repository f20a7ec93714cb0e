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
import json
from pathlib import Path

import pytest
from conftest import run_pymb
from release_outputs import DATABASES, OUTPUTS, messages, outputs, restore

from pymb.devices.mapreading import MapReading
from pymb.store import sample_dict
from pymb.store.reader import stored_after

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


def test_the_forwarder_reads_map_readings_into_the_release_messages(tmp_path: Path) -> None:
    """The forwarder's reader gives every sample as a map reading of its
    map (the hub's and the CoolPro's too): the JSON and the messages of both
    profiles are the release's, byte for byte."""
    for db in DATABASES:
        path = tmp_path / db
        restore(RELEASE / f"{Path(db).stem}.sql.gz", path)
        recs = stored_after(path, 0, limit=1_000_000)
        assert recs
        maps = [s.data for s in recs if isinstance(s.data, MapReading)]
        assert len(maps) == len(recs)
        assert {m.map.id for m in maps} == {"coolpro", "hub"}
        jsonl = "".join(json.dumps(sample_dict(s), allow_nan=False) + "\n" for s in recs)
        _same(f"{db}.jsonl", _expected(f"{db}.jsonl"), jsonl)
        plain, spark = messages(path, stored_after)
        _same(f"{db}.plain", _expected(f"{db}.plain"), plain)
        _same(f"{db}.sparkplug", _expected(f"{db}.sparkplug"), spark)


def test_pymb_export_writes_the_release_csv(tmp_path: Path) -> None:
    for db in DATABASES:
        restore(RELEASE / f"{Path(db).stem}.sql.gz", tmp_path / db)
        r = run_pymb("export", str(tmp_path / db), "--csv", "-", "--events", timeout=120)
        assert r.returncode == 0, r.stderr
        # the rows after export_csv's count; the pipe's text mode reads CR LF as LF
        want = _expected(f"{db}.long.csv").split("\n", 1)[1].replace("\r\n", "\n")
        _same(db, want, r.stdout)
