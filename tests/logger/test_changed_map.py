"""A map id keeps one text in a database: the stored samples are raw
registers decoded through the stored map, so a changed map under the same
id is refused (at the start: exit 2 and one line; on a SIGHUP reload: the
reload is refused and the running logger goes on) and the samples already
logged keep reading as they were logged."""

from __future__ import annotations

import signal
import sqlite3
from pathlib import Path

import pytest
from conftest import run_pymb, wait_until

pytest.register_assert_rewrite("servicekit")
from servicekit import StderrLines, count_rows, start_log  # noqa: E402

from pymb.devices.mapreading import MapReading  # noqa: E402
from pymb.errors import OutputError  # noqa: E402
from pymb.logger import Logger  # noqa: E402
from pymb.sim import SimulatorProcess  # noqa: E402
from pymb.store import samples_after  # noqa: E402

OLD = '''schema = "pymb.map/1"
[device]
id = "hist-meter"
table = "holding"
[[point]]
name = "current_a"
address = 0
type = "i32"
scale = 0.001
unit = "A"
example = -1.234
'''
NEW = OLD.replace('"i32"', '"u32"').replace("0.001", "0.01").replace("-1.234", "1.5")
MESSAGE = "map 'hist-meter' was logged with other text; give the changed map a new device id"


def _currents(db: Path) -> list[object]:
    out: list[object] = []
    for s in samples_after(db, 0, limit=100_000):
        assert isinstance(s.data, MapReading)
        out.append(s.data.values["current_a"])
    return out


def _stored(db: Path) -> str:
    con = sqlite3.connect(db)
    try:
        return str(con.execute("SELECT source FROM maps WHERE id = 'hist-meter'").fetchone()[0])
    finally:
        con.close()


def _config(tmp_path: Path, db: Path, endpoint: str) -> Path:
    config = tmp_path / "log.toml"
    config.write_text(f'''maps = ["meter.toml"]
[output]
path = "{db}"
commit_interval_s = 0.5
[[bus]]
tcp = "{endpoint}"
interval = 0.05
[[bus.device]]
type = "hist-meter"
address = 7
''')
    return config


def test_a_changed_map_under_the_same_id_is_refused_at_the_start(tmp_path: Path) -> None:
    meter, db = tmp_path / "meter.toml", tmp_path / "h.sqlite"
    meter.write_text(OLD)
    with SimulatorProcess(["--map", str(meter), "hist-meter:7", "--tcp", "127.0.0.1:0"],
                          quiet=True) as sim:
        r = run_pymb("log", "--map", str(meter), "--tcp", sim.endpoint, "hist-meter:7",
                     "--seconds", "1", "--interval", "0.05", "--out", str(db),
                     "--quiet")
        assert r.returncode == 0, r.stderr
        before = _currents(db)
        assert before
        assert all(v == pytest.approx(-1.234) for v in before)
        meter.write_text(NEW)
        r = run_pymb("log", "--map", str(meter), "--tcp", sim.endpoint, "hist-meter:7",
                     "--seconds", "1", "--interval", "0.05", "--out", str(db),
                     "--quiet")
        assert r.returncode == 2, r.stderr
        assert r.stderr.count("\n") == 1, r.stderr
        assert MESSAGE in r.stderr
        assert "Traceback" not in r.stderr
        # the same text again is fine (a new run appends)
        meter.write_text(OLD)
        r = run_pymb("log", "--map", str(meter), "--tcp", sim.endpoint, "hist-meter:7",
                     "--seconds", "1", "--interval", "0.05", "--out", str(db),
                     "--quiet")
        assert r.returncode == 0, r.stderr
    after = _currents(db)
    assert len(after) > len(before)
    assert all(v == pytest.approx(-1.234) for v in after)
    assert _stored(db) == OLD
    # and the export reads the old samples as they were logged
    e = run_pymb("export", str(db), "--csv", "-")
    assert e.returncode == 0, e.stderr
    assert "-1.234" in e.stdout
    assert "42949" not in e.stdout


def test_the_writer_refuses_a_changed_map_too(tmp_path: Path) -> None:
    """The Python API (no command line to check first): the writer refuses,
    the run ends with an OutputError, and what was stored is unchanged."""
    from pymb.commands.logconfig import load
    meter, db = tmp_path / "meter.toml", tmp_path / "w.sqlite"
    meter.write_text(OLD)
    with SimulatorProcess(["--map", str(meter), "hist-meter:7", "--tcp", "127.0.0.1:0"],
                          quiet=True) as sim:
        config = _config(tmp_path, db, sim.endpoint)
        assert Logger(load(config)[0]).run(1.0).exit_code == 0
        n = count_rows(db)
        meter.write_text(NEW)
        with pytest.raises(OutputError, match=MESSAGE):
            Logger(load(config)[0]).run(1.0)
    assert count_rows(db) == n
    assert _stored(db) == OLD
    assert all(v == pytest.approx(-1.234) for v in _currents(db))


def test_a_reload_with_a_changed_map_is_refused(tmp_path: Path) -> None:
    meter, db = tmp_path / "meter.toml", tmp_path / "r.sqlite"
    meter.write_text(OLD)
    with SimulatorProcess(["--map", str(meter), "hist-meter:7", "--tcp", "127.0.0.1:0"],
                          quiet=True) as sim:
        config = _config(tmp_path, db, sim.endpoint)
        proc = start_log("--config", str(config), cwd=tmp_path)
        err = StderrLines(proc)
        try:
            wait_until(lambda: count_rows(db) >= 5, "samples", alive=lambda: proc.poll() is None)
            meter.write_text(NEW)
            proc.send_signal(signal.SIGHUP)
            err.wait_for("SIGHUP: the new configuration is refused")
            assert MESSAGE in err.text(), err.text()
            before = count_rows(db)
            wait_until(lambda: count_rows(db) > before + 5, "logging on",
                       alive=lambda: proc.poll() is None)
            proc.send_signal(signal.SIGTERM)
            assert proc.wait(30) == 0, err.text()
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    assert _stored(db) == OLD
    assert all(v == pytest.approx(-1.234) for v in _currents(db))
    con = sqlite3.connect(db)
    try:
        refused = con.execute("SELECT message FROM events WHERE kind = 'reload'").fetchall()
    finally:
        con.close()
    assert any(MESSAGE in m for (m,) in refused), refused
