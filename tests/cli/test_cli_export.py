"""``pymb export`` as a real process: it never writes onto its input or
onto a file that is not its own; filters, names, signals."""

from __future__ import annotations

import csv
import signal
import subprocess
from pathlib import Path

import pytest
from clikit import digest, no_traceback
from conftest import PYMB, PYMB_ENV, run_pymb, wait_until
from dbwait import one_sample_database


def test_export_never_writes_onto_its_input(logged: Path) -> None:
    before = digest(logged)
    r = run_pymb("export", str(logged), "--csv", str(logged))
    no_traceback(r)
    assert r.returncode == 2
    assert "the database being exported" in r.stderr
    assert digest(logged) == before


def test_export_keeps_a_file_that_is_not_pymb_csv_unless_forced(logged: Path,
                                                                tmp_path: Path) -> None:
    notes = tmp_path / "notes.csv"
    notes.write_text("my,own,data\n1,2,3\n")
    r = run_pymb("export", str(logged), "--csv", str(notes))
    assert r.returncode == 2
    assert "--force" in r.stderr
    assert notes.read_text() == "my,own,data\n1,2,3\n"
    out = tmp_path / "out.csv"
    assert run_pymb("export", str(logged), "--csv", str(out)).returncode == 0
    assert run_pymb("export", str(logged), "--csv", str(out)).returncode == 0  # pymb's own: fine
    assert run_pymb("export", str(logged), "--csv", str(notes), "--force").returncode == 0
    assert notes.read_text().startswith("time_utc,")
    assert not list(tmp_path.glob(".pymb-export-*"))  # no temporary file left


def test_export_names_with_uri_characters_and_directories(logged: Path,
                                                          tmp_path: Path) -> None:
    for name in ("a%20b.sqlite", "x#y.sqlite", "what?.sqlite"):
        odd = tmp_path / name
        odd.write_bytes(logged.read_bytes())
        r = run_pymb("export", str(odd), "--csv", "-")
        no_traceback(r)
        assert r.returncode == 0, (name, r.stderr)
        assert len(r.stdout.splitlines()) > 10
    r = run_pymb("export", str(tmp_path), "--csv", "-")
    no_traceback(r)
    assert r.returncode == 2
    assert "is a directory" in r.stderr
    text = tmp_path / "text.sqlite"
    text.write_text("hello\n")
    r = run_pymb("export", str(text), "--csv", "-")
    assert r.returncode == 2
    assert "not a database written by pymb" in r.stderr


def test_export_device_by_syntax_or_name_and_unknown_lists(logged: Path) -> None:
    by_spec = run_pymb("export", str(logged), "--csv", "-", "--device", "hub:250")
    by_name = run_pymb("export", str(logged), "--csv", "-", "--device", "hub-250")
    assert by_spec.returncode == 0
    assert by_spec.stdout == by_name.stdout
    rows = list(csv.DictReader(by_spec.stdout.splitlines()))
    assert rows
    assert {r["device"] for r in rows} == {"hub-250"}
    r = run_pymb("export", str(logged), "--csv", "-", "--device", "hub:9")
    assert r.returncode == 2
    assert "no device 'hub:9'" in r.stderr
    assert "coolpro-40" in r.stderr
    assert "hub-250" in r.stderr


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP])
def test_export_stopped_by_a_signal_leaves_no_temporary_file(logged: Path, tmp_path: Path,
                                                             sig: int) -> None:
    """SIGTERM (a service stopped) or SIGHUP (the terminal closed) mid-export:
    the previous CSV stays as it was and no hidden temporary file (as big as
    the export) is left behind to fill the disk."""
    out = tmp_path / "out.csv"
    r = run_pymb("export", str(logged), "--since", "2100-01-01", "--csv", str(out))
    assert r.returncode == 0, r.stderr
    before = digest(out)
    p = subprocess.Popen([*PYMB, "export", str(logged), "--csv", str(out)], env=PYMB_ENV,
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        wait_until(lambda: [f for f in tmp_path.iterdir() if f.name.startswith(".pymb-export-")
                            and f.stat().st_size > 0], "the export's temporary file", 60,
                   alive=lambda: p.poll() is None, every=0.01)
        p.send_signal(sig)
        _, err = p.communicate(timeout=30)
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
    assert "Traceback" not in err, err
    assert p.returncode == 128 + sig, (p.returncode, err)
    assert sorted(f.name for f in tmp_path.iterdir()) == ["out.csv"]
    assert digest(out) == before


@pytest.mark.parametrize(("argv", "message"), [
    (["--since", ""], "--since needs an ISO 8601 time, got ''"),
    (["--since", " "], "--since needs an ISO 8601 time, got ' '"),
    (["--since", "yesterday"], "--since needs an ISO 8601 time, got 'yesterday'"),
    (["--device", ""], "no device ''"),
])
def test_export_refuses_an_empty_filter(tmp_path: Path, argv: list[str], message: str) -> None:
    db = tmp_path / "log.sqlite"
    one_sample_database(db)
    r = run_pymb("export", str(db), "--csv", "-", *argv, timeout=60)
    assert r.returncode == 2, r
    assert r.stdout == ""
    assert message in r.stderr
    assert "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def test_export_since_still_filters(tmp_path: Path) -> None:
    db = tmp_path / "log.sqlite"
    one_sample_database(db)
    for since, rows in (("2027-01-15T08:00:00Z", 700), ("2027-01-15T08:00:01Z", 0)):
        r = run_pymb("export", str(db), "--csv", "-", "--since", since, timeout=60)
        assert r.returncode == 0, r.stderr
        assert len(r.stdout.splitlines()) == 1 + rows
