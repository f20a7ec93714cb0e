"""``pymb info``, ``pymb plot`` and ``export``'s wide layout and filters, on
real SQLite files written by pymb's writer: the figures are the database's
(checked by SQL of the test's own), the images are valid files of the size
asked for with the database's rows plotted, read-only media are read without
a file left behind, and every mistake is one line."""

from __future__ import annotations

import csv
import io
import json
import math
import os
import shutil
import sqlite3
import struct
import subprocess
import sys
import tempfile
from array import array
from collections.abc import Iterator
from datetime import UTC, datetime
from pathlib import Path

import pytest
import reference as ref
from conftest import PYMB, PYMB_ENV, run_pymb

from pymb.commands.plot import figure
from pymb.devices import CoolProStatus, CoolProTelemetry, decode_hub
from pymb.extras import install_hint
from pymb.store import DeviceInfo, Event, Sample, SqliteSink, series

T0 = 1_796_000_000.0  # 2026-11-30T00:53:20Z
HUB = DeviceInfo("sensors", "/dev/ttyUSB0", "hub", 7, "hub-7", 100, 0.1)
PSU = DeviceInfo("psu", "/dev/ttyUSB1", "coolpro", 40, "coolpro-40")
N = 12


def _hub_regs(i: int) -> array[int]:
    regs = array("H", [0xFFFF] * 700)  # offline everywhere ...
    regs[2] = 0xFFFF if i == 4 else 200 + i  # channel 3's temperature (offline at i = 4)
    regs[100 + 2] = 450 + i  # channel 3's humidity (0.1 %)
    regs[0] = 0x8000 | (10 + i)  # channel 1: -1.0 - 0.1 i °C
    return regs


def _telemetry(i: int) -> CoolProTelemetry:
    regs = array("H", [24000 + i, 1000, 12000 + 10 * i, 500, 30000, i, 0, 1])
    vin, iin, vout, iout, temp, up, status = ref.coolpro_telemetry(list(regs))
    return CoolProTelemetry(vin, iin, vout, iout, temp, up, CoolProStatus(status), regs)


def _make(path: Path) -> None:
    sink = SqliteSink(path)
    for i in range(N):
        sink.write(Sample(HUB, T0 + i, float(i), decode_hub(_hub_regs(i), 0.1)))
        sink.write(Sample(PSU, T0 + i + 0.5, i + 0.5, _telemetry(i)))
    sink.event(Event(T0 + 1, 1.0, "sensors", HUB, "timeout", None, "no reply"))
    sink.event(Event(T0 + 2, 2.0, "sensors", HUB, "timeout", None, "no reply"))
    sink.event(Event(T0 + 3, 3.0, "psu", PSU, "reconnect", None, "back"))
    sink.close()


@pytest.fixture(scope="module")
def db(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("data") / "log.sqlite"
    _make(path)
    return path


def _pymb(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    done = run_pymb(*args, cwd=cwd, timeout=120)
    assert "Traceback" not in done.stderr, done.stderr
    return done


# -- info ------------------------------------------------------------------------------


def test_info_says_what_the_database_holds(db: Path) -> None:
    con = sqlite3.connect(db)
    con.execute("CREATE TABLE outbox(name TEXT PRIMARY KEY, sample_id INTEGER)")
    con.execute("INSERT INTO outbox VALUES ('mqtt', 20)")
    con.commit()
    (total,) = con.execute("SELECT COUNT(*) FROM samples").fetchone()
    (unsent,) = con.execute("SELECT COUNT(*) FROM samples WHERE id > 20").fetchone()
    con.close()
    try:
        done = _pymb("info", str(db), "--json")
        assert done.returncode == 0, done.stderr
        doc = json.loads(done.stdout)
        assert doc["samples"] == total == 2 * N
        assert {d["name"]: d["samples"] for d in doc["devices"]} == {"hub-7": N,
                                                                    "coolpro-40": N}
        assert doc["first"] == T0
        assert doc["last"] == T0 + N - 1 + 0.5
        assert doc["first_iso"] == "2026-11-30T00:53:20.000Z"
        assert doc["faults"] == {"timeout": 2}
        assert doc["events"]["reconnect"] == 1
        assert doc["backlog"] == {"mqtt": unsent}
        assert unsent == 4
        assert doc["size_bytes"] == db.stat().st_size
        text = _pymb("info", str(db)).stdout
        assert "  faults      2: 2 timeout\n" in text
        assert "  forwarder   mqtt: 4 sample(s) not yet sent\n" in text
        assert f"hub-7       hub:7 on sensors (/dev/ttyUSB0), 100 channels: {N} samples" in text
    finally:
        con = sqlite3.connect(db)
        con.execute("DROP TABLE outbox")
        con.commit()
        con.close()


def _read_only_runner(folder: Path) -> list[str]:
    """The command prefix that runs a command which cannot write ``folder``:
    as it is for a user other than root (the folder is mode 0555); for root,
    who may write anywhere, inside a mount namespace where the folder is a
    read-only bind mount (EROFS, as a card mounted read-only), or else as
    nobody."""
    if os.geteuid() != 0:
        return []
    unshare, sh = shutil.which("unshare"), shutil.which("sh")
    if unshare and sh:
        script = 'mount --bind "$0" "$0" && mount -o remount,ro,bind "$0" && exec "$@"'
        prefix = [unshare, "--mount", sh, "-c", script, str(folder)]
        probe = subprocess.run([*prefix, sh, "-c", 'touch "$0/probe"', str(folder)],
                               capture_output=True, text=True, timeout=30, check=False)
        if probe.returncode != 0 and "Read-only file system" in probe.stderr:
            return prefix
    setpriv = shutil.which("setpriv")
    assert setpriv, "neither a mount namespace nor setpriv: cannot make read-only media"
    return [setpriv, "--reuid=65534", "--regid=65534", "--clear-groups"]


@pytest.fixture
def readonly_copy(db: Path) -> Iterator[tuple[Path, list[str]]]:
    """A copy of the database in a directory that the command run with the
    prefix given cannot write (read-only media)."""
    folder = Path(tempfile.mkdtemp(prefix="pymb-ro-"))
    shutil.copy(db, folder / db.name)
    os.chmod(folder / db.name, 0o444)
    os.chmod(folder, 0o555)
    try:
        yield folder / db.name, _read_only_runner(folder)
    finally:
        os.chmod(folder, 0o755)
        shutil.rmtree(folder)


def test_info_and_export_read_only_media_and_leave_nothing(
        readonly_copy: tuple[Path, list[str]]) -> None:
    path, prefix = readonly_copy
    before = sorted(os.listdir(path.parent))
    env = {**PYMB_ENV, "HOME": "/nonexistent", "MPLCONFIGDIR": tempfile.gettempdir()}
    for args in (["info", str(path)], ["export", str(path), "--csv", "-", "--layout", "wide"]):
        done = subprocess.run([*prefix, *PYMB, *args], capture_output=True, text=True,
                              env=env, cwd="/", timeout=120, check=False)
        assert done.returncode == 0, done.stderr
        assert sorted(os.listdir(path.parent)) == before
    assert len(done.stdout.splitlines()) == 1 + 2 * N


# -- plot ------------------------------------------------------------------------------


def _png_size(path: Path) -> tuple[int, int]:
    head = path.read_bytes()[:24]
    assert head[:8] == b"\x89PNG\r\n\x1a\n"
    assert head[12:16] == b"IHDR"
    w, h = struct.unpack(">II", head[16:24])
    return w, h


def test_plot_writes_png_and_svg_of_the_size_asked_for(db: Path, tmp_path: Path) -> None:
    done = _pymb("plot", str(db), "hub:7", "temperature_c", "--channel", "3", "--size",
                 "640x480", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    png = tmp_path / "hub-7-temperature_c-ch3.png"
    assert _png_size(png) == (640, 480)
    svg = tmp_path / "v.svg"
    done = _pymb("plot", str(db), "coolpro-40", "output_voltage_v", "-o", str(svg),
                 "--size", "800x300")
    assert done.returncode == 0, done.stderr
    import xml.etree.ElementTree as ET

    root = ET.parse(svg).getroot()
    assert root.tag.endswith("svg")
    assert (root.get("width"), root.get("height")) == ("800px", "300px")
    # replacing its own image is fine; a user's file is kept
    again = _pymb("plot", str(db), "coolpro-40", "output_voltage_v", "-o", str(svg))
    assert again.returncode == 0, again.stderr
    note = tmp_path / "note.png"
    note.write_text("mine")
    refused = _pymb("plot", str(db), "coolpro-40", "output_voltage_v", "-o", str(note))
    assert refused.returncode == 2
    assert note.read_text() == "mine"
    assert refused.stderr == (f"pymb plot: {note} exists and is not an image pymb plot wrote: "
                              "refusing to overwrite it (--force to do it anyway)\n")


def _view_rows(db: Path, sql: str, args: tuple[object, ...]) -> list[tuple[float, float]]:
    con = sqlite3.connect(db)
    try:
        return [(t, math.nan if v is None else v) for t, v in con.execute(sql, args)]
    finally:
        con.close()


def _same(a: list[float], b: list[float]) -> bool:
    return len(a) == len(b) and all((math.isnan(x) and math.isnan(y)) or x == pytest.approx(y)
                                    for x, y in zip(a, b, strict=True))


@pytest.mark.parametrize(("device", "quantity", "channel", "sql"), [
    ("hub:7", "temperature_c", 3, "SELECT time_utc, temperature_c FROM hub_readings "
                                  "WHERE device = ? AND channel = ? ORDER BY time_utc"),
    ("hub-7", "temperature_c", 1, "SELECT time_utc, temperature_c FROM hub_readings "
                                  "WHERE device = ? AND channel = ? ORDER BY time_utc"),
    ("coolpro", "output_voltage_v", None, "SELECT time_utc, output_voltage_v FROM "
                                          "coolpro_readings WHERE device = ? ORDER BY time_utc"),
])
def test_the_plotted_series_is_the_databases(db: Path, device: str, quantity: str,
                                             channel: int | None, sql: str) -> None:
    s = series(db, device, quantity, channel=channel, since=T0 + 1, until=T0 + 9)
    args: tuple[object, ...] = (s.device, channel) if channel else (s.device,)
    rows = [r for r in _view_rows(db, sql, args) if T0 + 1 <= r[0] < T0 + 9]
    assert len(rows) == 8
    fig = figure(s, (500, 400))
    (line,) = fig.axes[0].lines
    xs = [x.timestamp() for x in line.get_xdata(orig=True)]
    ys = [float(y) for y in line.get_ydata(orig=True)]
    assert xs == [t for t, _ in rows]
    assert _same(ys, [v for _, v in rows])
    if channel == 3:
        assert math.isnan(ys[3])  # offline at T0 + 4: a gap, not a value
        assert ys[0] == pytest.approx(20.1)
    fig.canvas.draw()  # it renders
    assert fig.get_size_inches() * fig.dpi == pytest.approx([500, 400])


def test_plot_without_matplotlib_says_how_to_install_it(db: Path, tmp_path: Path) -> None:
    code = ("import sys, runpy\n"
            "sys.modules['matplotlib'] = None  # as if the plot extra were not installed\n"
            "sys.argv = ['pymb', 'plot', sys.argv[1], 'coolpro', 'temperature_c']\n"
            "runpy.run_module('pymb', run_name='__main__')\n")
    done = subprocess.run([sys.executable, "-c", code, str(db)], capture_output=True,
                          text=True, env=PYMB_ENV, cwd=tmp_path, timeout=120, check=False)
    assert done.returncode == 2
    assert done.stderr == f"pymb plot: drawing needs matplotlib: {install_hint('plot')}\n"
    assert not list(tmp_path.iterdir())


# -- export ----------------------------------------------------------------------------


def test_export_wide_one_row_per_sample(db: Path) -> None:
    done = _pymb("export", str(db), "--csv", "-", "--layout", "wide", "--device", "hub:7",
                 "--channel", "1,3", "--quantity", "temperature_c,humidity_pct",
                 "--since", datetime.fromtimestamp(T0 + 2, UTC).isoformat(),
                 "--until", datetime.fromtimestamp(T0 + 6, UTC).isoformat())
    assert done.returncode == 0, done.stderr
    rows = list(csv.DictReader(io.StringIO(done.stdout)))
    assert [float(r["time_utc"]) for r in rows] == [T0 + i for i in range(2, 6)]
    assert list(rows[0])[6:] == ["temperature_c_1", "humidity_pct_1", "temperature_c_3",
                                 "humidity_pct_3"]
    assert [r["temperature_c_3"] for r in rows] == ["20.2", "20.3", "", "20.5"]
    assert [r["temperature_c_1"] for r in rows] == ["-1.2", "-1.3", "-1.4", "-1.5"]
    assert rows[0]["humidity_pct_3"] == "45.2"
    assert all(r["time"].endswith("Z") for r in rows)


def test_export_long_filters(db: Path) -> None:
    done = _pymb("export", str(db), "--csv", "-", "--channel", "3", "--quantity",
                 "temperature_c", "--until", datetime.fromtimestamp(T0 + 5, UTC).isoformat())
    rows = list(csv.DictReader(io.StringIO(done.stdout)))
    assert [(r["channel"], r["quantity"], r["value"], r["state"]) for r in rows] == [
        ("3", "temperature_c", "20.0", "value"), ("3", "temperature_c", "20.1", "value"),
        ("3", "temperature_c", "20.2", "value"), ("3", "temperature_c", "20.3", "value"),
        ("3", "temperature_c", "", "offline")]
    psu = _pymb("export", str(db), "--csv", "-", "--layout", "wide", "--device", "coolpro")
    rows = list(csv.DictReader(io.StringIO(psu.stdout)))
    assert len(rows) == N
    assert rows[1]["output_voltage_v"] == "12.01"


def test_export_wide_of_an_empty_database(tmp_path: Path) -> None:
    SqliteSink(tmp_path / "new.sqlite").close()
    done = _pymb("export", str(tmp_path / "new.sqlite"), "--csv", "-", "--layout", "wide")
    assert done.returncode == 0, done.stderr
    assert done.stdout == "time_utc,time,bus,device,type,address\n"


def test_views_name_the_states(db: Path) -> None:
    con = sqlite3.connect(db)
    rows = con.execute("SELECT time, temperature_c_state, temperature_c_state_name, "
                       "humidity_pct_state_name FROM hub_readings WHERE channel = 3 "
                       "ORDER BY time_utc").fetchall()
    names = dict(con.execute("SELECT code, name FROM states"))
    con.close()
    assert rows[4][1:3] == (1, "offline")
    assert all(names[code] == name for _, code, name, _ in rows)
    assert rows[0][0] == "2026-11-30T00:53:20.000Z"


# -- mistakes: one line each, nothing written --------------------------------------------


@pytest.mark.parametrize(("argv", "message"), [
    (["info", "missing.sqlite"], "pymb info: no such database: missing.sqlite"),
    (["info", "."], "pymb info: . is a directory, not a database"),
    (["info", "notes.txt"], "pymb info: notes.txt is not a database written by pymb"),
    (["plot", "DB", "hub", "temperature_c"], "pymb plot: hub-7 is a hub: give --channel (1..100)"),
    (["plot", "DB", "hub", "temperature_c", "--channel", "101"],
     "pymb plot: --channel 101: hub-7 has channels 1..100"),
    (["plot", "DB", "coolpro", "temperature_c", "--channel", "1"],
     "pymb plot: --channel is for a hub; coolpro-40 is a coolpro"),
    (["plot", "DB", "coolpro", "vout"], "pymb plot: coolpro-40 (coolpro) has no quantity 'vout'"),
    (["plot", "DB", "pump", "temperature_c"], "pymb plot: no device 'pump' in DB; it has: "
     "hub-7 (hub:7 on sensors), coolpro-40 (coolpro:40 on psu)"),
    (["plot", "DB", "coolpro", "temperature_c", "-o", "t.jpg"],
     "pymb plot: -o t.jpg: the file name must end in .png or .svg"),
    (["plot", "DB", "coolpro", "temperature_c", "--size", "10x10"],
     "pymb plot: --size needs WIDTHxHEIGHT in pixels, each 100..10000 (e.g. 1000x500), "
     "got '10x10'"),
    (["plot", "DB", "coolpro", "temperature_c", "--since", "2100-01-01"],
     "pymb plot: no samples of coolpro-40's temperature_c in DB in that span"),
    (["plot", "DB", "coolpro", "temperature_c", "--since", "2026-12-02", "--until", "2026-12-01"],
     "pymb plot: --until (2026-12-01) must be after --since (2026-12-02)"),
    (["export", "DB", "--csv", "-", "--until", "soon"],
     "pymb export: --until needs an ISO 8601 time, got 'soon'"),
    (["export", "DB", "--csv", "-", "--layout", "wide", "--events"],
     "pymb export: --events is for the long layout (an event is no sample)"),
    (["export", "DB", "--csv", "-", "--channel", "0"],
     "pymb export: bad --channel '0': channels 1..100, e.g. 1-20 or 1-10,40"),
    (["export", "DB", "--csv", "-", "--quantity", "temprature_c"],
     "pymb export: unknown --quantity 'temprature_c'; did you mean 'temperature_c'?"),
    (["export", "DB", "--csv", "-", "--layout", "wide", "--device", "coolpro", "--channel", "3"],
     "pymb export: no value to export: the --channel and --quantity chosen match nothing"),
])
def test_mistakes_are_one_line(db: Path, tmp_path: Path, argv: list[str], message: str) -> None:
    (tmp_path / "notes.txt").write_text("my notes\n")
    before = sorted(os.listdir(tmp_path))
    argv = [str(db) if a == "DB" else a for a in argv]
    done = _pymb(*argv, cwd=tmp_path)
    assert done.returncode == 2
    assert done.stderr.startswith(message.replace("DB", str(db))), done.stderr
    assert len(done.stderr.splitlines()) == 1
    assert sorted(os.listdir(tmp_path)) == before
