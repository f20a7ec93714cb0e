"""Storage faults are survivable: a full disk (a small tmpfs), an emergency
read-only remount (ext4 on a loop device, its error handler triggered), the
database's directory removed. Each ends ``pymb log`` with exit 5 and one
line giving the operating system's reason and what to do; what was
committed stays; a restart resumes once the fault is gone.

Real processes (``pymb log`` against a simulated hub and CoolPro on Modbus
TCP in its own process) on real file systems; needs root (tests/disks.py).
"""

from __future__ import annotations

import shutil
import sqlite3
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import PYMB, PYMB_ENV, run_pymb, wait_until
from dbwait import wait_for
from docblocks import claim_one
from eventlines import without_events

pytest.register_assert_rewrite("disks")
from disks import LoopDisk, Tmpfs, need_root  # noqa: E402

from pymb.sim import SimulatorProcess  # noqa: E402

SAMPLES = "SELECT COUNT(*) FROM samples"


@pytest.fixture
def devices() -> Iterator[str]:
    """A simulated hub and CoolPro on Modbus TCP in their own process: HOST:PORT."""
    sim = SimulatorProcess(["hub:1", "coolpro:40", "--tcp", "127.0.0.1:0"], quiet=True).start()
    try:
        yield sim.endpoint
    finally:
        sim.stop()


def _log(endpoint: str, db: Path, *extra: str) -> subprocess.Popen[str]:
    """``pymb log`` of both devices, committing twice a second (readers see it)."""
    return subprocess.Popen([*PYMB, "log", "hub:1", "coolpro:40", "--tcp", endpoint, "--out",
                             str(db), "--quiet", "--commit-interval", "0.5", *extra],
                            stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=PYMB_ENV)


def _ids(db: Path) -> set[int]:
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    try:
        return {i for (i,) in con.execute("SELECT id FROM samples")}
    finally:
        con.close()


def _intact(db: Path, seen: set[int]) -> None:
    """The database is whole and holds every sample a reader saw committed."""
    con = sqlite3.connect(db)
    try:
        assert con.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
        ids = {i for (i,) in con.execute("SELECT id FROM samples")}
    finally:
        con.close()
    assert seen <= ids, f"{len(seen - ids)} committed samples lost"


def _failed(proc: subprocess.Popen[str], *words: str) -> str:
    """The logger ended with exit 5 and one line holding ``words``; that line."""
    _, err = proc.communicate(timeout=120)
    lines = without_events(err)  # the events are lines on stderr too (not a terminal)
    assert proc.returncode == 5, err
    assert len(lines) == 1, err
    for w in words:
        assert w in lines[0], lines[0]
    assert "rollback" not in lines[0]
    assert "Traceback" not in err
    return lines[0]


def test_a_full_disk(devices: str, tmp_path: Path) -> None:
    need_root()
    with Tmpfs(tmp_path / "card", 16384) as card:
        card.fill(leave=9 << 20)  # a card nearly full already: 9 MB left
        db = card.mountpoint / "data.sqlite"
        # Logging fills the disk: exit 5, the reason, what to do.
        proc = _log(devices, db)
        seen: set[int] = set()

        def ended() -> bool:  # what a reader saw committed, up to the end
            if proc.poll() is not None:
                return True
            seen.update(_ids(db) if db.exists() else ())
            return False

        wait_until(ended, "the logger to fill the disk", 120, every=0.1)
        line = _failed(proc, "No space left on device (ENOSPC)", "free some space")
        # docs/reliability.md shows this line, for data.sqlite in the current folder
        shown = claim_one("docs/reliability.md", "text", how="compare",
                          contains="No space left on device").text.strip()
        assert line.replace(str(db), "data.sqlite") == shown, (line, shown)
        _intact(db, seen)
        # The restart a service does: the same, not a usage error.
        _failed(_log(devices, db, "--seconds", "30"), "No space left on device (ENOSPC)")
        # --max-mb opens the full database and trims it to its bound, and logs.
        before = _ids(db)
        done = run_pymb("log", "hub:1", "coolpro:40", "--tcp", devices, "--out", str(db),
                        "--max-mb", "1.5", "--seconds", "3", timeout=120)
        assert done.returncode == 0, done.stderr
        after = _ids(db)
        assert max(after) > max(before)
        assert db.stat().st_size <= 1_500_000
        # Space freed: a plain restart resumes.
        (card.mountpoint / "filler").unlink()
        done = run_pymb("log", "hub:1", "coolpro:40", "--tcp", devices, "--out", str(db),
                        "--seconds", "2", timeout=120)
        assert done.returncode == 0, done.stderr
        assert max(_ids(db)) > max(after)


def test_the_directory_removed_while_logging(devices: str, tmp_path: Path) -> None:
    where = tmp_path / "state"
    where.mkdir()
    db = where / "data.sqlite"
    proc = _log(devices, db)
    try:
        wait_for(db, SAMPLES, at_least=5, proc=proc)
        shutil.rmtree(where)
        _failed(proc, "was removed", "restore the directory")
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()


def test_an_emergency_read_only_remount(devices: str, tmp_path: Path) -> None:
    need_root()
    disk = LoopDisk(tmp_path / "card.img", tmp_path / "card", size_mb=32,
                    options="errors=remount-ro")
    try:
        db = disk.mountpoint / "data.sqlite"
        proc = _log(devices, db)
        wait_for(db, SAMPLES, at_least=50, proc=proc)
        seen = _ids(db)
        disk.fail()  # ext4 meets an error: read-only at once, nothing flushed
        # The first write after the error meets the aborted journal (EIO),
        # later ones the read-only mount (EROFS): either is said as it is.
        line = _failed(proc, "cannot write to")
        assert any(w in line for w in ("(EIO); the disk failed", "(EROFS); the file system"))
        disk.umount()
        disk = LoopDisk(disk.image, tmp_path / "card2", fresh=False)
        _intact(disk.mountpoint / "data.sqlite", seen)
    finally:
        disk.umount()


def test_export_reads_read_only_media_and_leaves_nothing(devices: str, tmp_path: Path) -> None:
    need_root()
    disk = LoopDisk(tmp_path / "card.img", tmp_path / "card", size_mb=16)
    try:
        db = disk.mountpoint / "data.sqlite"
        done = run_pymb("log", "coolpro:40", "--tcp", devices, "--out", str(db), "--seconds",
                        "1", timeout=120)
        assert done.returncode == 0, done.stderr
        files = sorted(p.name for p in disk.mountpoint.iterdir())
        out = tmp_path / "rw.csv"
        done = run_pymb("export", str(db), "--csv", str(out))
        assert done.returncode == 0, done.stderr
        assert sorted(p.name for p in disk.mountpoint.iterdir()) == files
        disk.remount_ro()
        done = run_pymb("export", str(db), "--csv", str(tmp_path / "ro.csv"))
        assert done.returncode == 0, done.stderr
        assert (tmp_path / "ro.csv").read_text() == out.read_text()
    finally:
        disk.umount()


def test_the_record_of_unsent_samples_deleted_survives_the_trims(tmp_path: Path) -> None:
    """A long outage under --max-mb: trim after trim deletes samples the
    forwarder never sent; one ``trim`` event keeps the count of them all."""
    from array import array

    from pymb.devices import CoolProStatus, CoolProTelemetry
    from pymb.store import DeviceInfo, Sample, SqliteSink

    db = tmp_path / "data.sqlite"
    sink = SqliteSink(db, max_bytes=1_000_000)
    sink.db.execute("CREATE TABLE outbox(name TEXT PRIMARY KEY, sample_id INTEGER NOT NULL)")
    sink.db.execute("INSERT INTO outbox VALUES ('mqtt://broker/plain/node', 0)")
    info = DeviceInfo("bus", "port", "coolpro", 40, "psu")
    data = CoolProTelemetry(24.0, 1.0, 12.0, 2.0, 30.0, 1, CoolProStatus(0), array("H", [7] * 8))
    for i in range(300):
        now = time.time()  # later than the trim events before: as a logger's samples
        sink.write_batch([Sample(info, now, float(i), data)] * 100)
        sink.commit()
    sink.close()
    con = sqlite3.connect(db)
    events = con.execute("SELECT code, message FROM events WHERE kind = 'trim'").fetchall()
    low = con.execute("SELECT MIN(id) FROM samples").fetchone()[0]
    con.close()
    assert sink.trimmed > 0
    assert len(events) == 1, events
    assert events[0][0] == sink.trimmed == low - 1
    assert events[0][1].endswith(f"(ids 1..{low - 1})")
