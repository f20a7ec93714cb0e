"""Storage format 2: registers once, decoded by plain-SQL views; old files;
the reader of a forwarder; report by exception; the size bound with its WAL."""

from __future__ import annotations

import math
import random
import re
import sqlite3
import subprocess
import sys
import time
from array import array
from pathlib import Path

import pytest
from conftest import PYMB, PYMB_ENV, ROOT, run_pymb

from pymb.bench.layouts import write_format1
from pymb.devices import HUB, HubReading, State, decode_hub
from pymb.devices.hubreading import BLOCKS, CHANNELS, HUB_REGISTERS
from pymb.errors import InvalidArgument
from pymb.store import (
    DeviceInfo,
    Event,
    OnChange,
    Sample,
    SqliteSink,
    export_csv,
    sample_dict,
    samples_after,
)
from pymb.store.schema import host_words, wire_bytes

T0 = 1_800_000_000.0
FIELDS = [b.name for b in BLOCKS]
#: each block's markers in either humidity unit
MARKERS = {name: list(dict.fromkeys(m for unit in (1, 0.1) for m in
                                    HUB.configure(humidity_unit=unit).points[name].markers))
           for name in FIELDS}


def random_registers(rng: random.Random) -> array[int]:
    """700 registers: values of every kind and every marker of [HUB] / [NOTES]."""
    regs = array("H")
    for name in FIELDS:
        for _ in range(CHANNELS):
            pick = rng.random()
            if pick < 0.1:
                regs.append(0xFFFF)
            elif pick < 0.2:
                regs.append(rng.choice(MARKERS[name]))
            elif pick < 0.3:
                regs.append(rng.choice([0, 0x8000, 0x7FFF, 0x8001, 0xFFFE]))
            else:
                regs.append(rng.randrange(0x10000))
    return regs


def views_equal_c(con: sqlite3.Connection, sample_id: int, r: object) -> None:
    from pymb.devices import HubReading

    assert isinstance(r, HubReading)
    c = r.channels
    rows = con.execute("SELECT * FROM hub WHERE sample_id = ? ORDER BY channel",
                       (sample_id,)).fetchall()
    assert [row[1] for row in rows] == list(range(1, c + 1))
    for row in rows:
        ch = row[1] - 1
        for b in range(len(FIELDS)):
            v, st = r.values[b * c + ch], r.raw_states[b * c + ch]
            got_v, got_st = row[2 + b], row[2 + len(FIELDS) + b]
            assert got_st == st, (FIELDS[b], ch + 1)
            assert (got_v is None) == math.isnan(v), (FIELDS[b], ch + 1, got_v, v)
            if got_v is not None:
                assert got_v == v, (FIELDS[b], ch + 1, got_v, v)


def test_the_views_decode_exactly_as_the_c_core(tmp_path: Path) -> None:
    rng = random.Random(12)
    db = tmp_path / "views.sqlite"
    sink = SqliteSink(db)
    cases = []
    for i in range(12):
        channels = rng.choice([100, 50, 7])
        choices: list[float | tuple[float, ...]] = [
            0.1, 1, tuple(rng.choice([1, 0.1]) for _ in range(channels))]
        units = rng.choice(choices)
        unsupported = [name for name in FIELDS if rng.random() < 0.2]
        regs = random_registers(rng)
        r = decode_hub(regs, list(units) if isinstance(units, tuple) else units,
                       channels=channels, unsupported=unsupported)
        dev = DeviceInfo("b", "/dev/ttyX", "hub", 9, "hub-9", channels, units)
        sink.write(Sample(dev, T0 + i, float(i), r))
        cases.append(r)
    sink.close()
    con = sqlite3.connect(db)
    for i, r in enumerate(cases):
        views_equal_c(con, i + 1, r)
    # The raw registers are there once, exactly as read.
    blob = con.execute("SELECT registers FROM samples WHERE id = 1").fetchone()[0]
    want = array("H", cases[0].registers)
    if sys.byteorder == "little":
        want.byteswap()
    assert blob == want.tobytes()
    # ... and the reader gives back what the C decoder gave.
    got = samples_after(db, 0, 100)
    assert [s.id for s in got] == list(range(1, 13))
    for s, r in zip(got, cases, strict=True):
        assert isinstance(s.data, HubReading)
        assert s.data.as_dict() == r.as_dict()
        assert s.data.raw_states == r.raw_states
    con.close()


def test_coolpro_view_and_reader(tmp_path: Path) -> None:
    from pymb.devices import CoolProStatus, CoolProTelemetry

    # [CP] worked values: 24.5 V, 3.25 A, 24.0 V, 3.20 A; uptime 4464, 1 -> 70000 s
    regs = array("H", [0x5FB4, 0x0CB2, 0x5DC0, 0x0C80, 41234, 4464, 1, 0x8041])
    t = CoolProTelemetry(24.5, 3.25, 24.0, 3.2, 41.234, 70000, CoolProStatus(0x8041), regs)
    db = tmp_path / "cp.sqlite"
    sink = SqliteSink(db)
    sink.write(Sample(DeviceInfo("b", "p", "coolpro", 40, "psu"), T0, 1.0, t))
    sink.close()
    con = sqlite3.connect(db)
    row = con.execute("SELECT device, input_voltage_v, input_current_a, output_voltage_v, "
                      "output_current_a, temperature_c, uptime_s, status "
                      "FROM coolpro_readings").fetchone()
    assert row == ("psu", 24.5, 3.25, 24.0, 3.2, 41.234, 70000, 0x8041)
    con.close()
    (s,) = samples_after(db, 0)
    assert isinstance(s.data, CoolProTelemetry)
    assert s.data.uptime_s == 70000
    assert s.data.input_voltage_v == 24.5
    assert s.data.status == CoolProStatus(0x8041)
    assert s.data.registers == regs
    d = sample_dict(s)
    assert d["sample"] == 1
    assert d["device"] == "psu"
    assert d["status_flags"] == ["SYSTEM_STARTUP", "TEMPERATURE_SENSOR_FAULT"]


def _readme_queries() -> list[str]:
    """The queries the README and docs/storage.md show."""
    text = "\n".join((ROOT / page).read_text(encoding="utf-8")
                     for page in ("README.md", "docs/storage.md"))
    return [q.replace("\n", " ") for q in
            re.findall(r'sqlite3 data\.sqlite "([^"]+)"', text, flags=re.S)]


def test_the_readme_queries_use_the_time_index_in_stock_sqlite3(tmp_path: Path) -> None:
    queries = _readme_queries()
    assert len(queries) >= 4
    db = tmp_path / "data.sqlite"
    rng = random.Random(3)
    hub = DeviceInfo("b", "p", "hub", 250, "hub-250")
    cp = DeviceInfo("b", "p", "coolpro", 40, "coolpro-40")
    from pymb.devices import CoolProStatus, CoolProTelemetry

    tele = CoolProTelemetry(1, 1, 1, 1, 1, 1, CoolProStatus(0), array("H", range(8)))
    t0 = time.time() - 2000  # the README asks for the value now
    for on_change in (None, OnChange(60.0, {"temperature_c": 0.5})):
        sink = SqliteSink(db, on_change=on_change)
        for i in range(300):
            sink.write(Sample(cp, t0 + i + (1000 if on_change else 0), float(i), tele))
            sink.write(Sample(hub, t0 + i + (1000 if on_change else 0), float(i),
                              decode_hub(random_registers(rng))))
        sink.event(Event(t0, 0.0, "b", hub, "timeout", None, "late"))
        sink.close()
    con = sqlite3.connect(db)
    for q in queries:
        plan = [r[3] for r in con.execute("EXPLAIN QUERY PLAN " + q)]
        assert not any("TEMP B-TREE" in p for p in plan), (q, plan)
        assert all(re.search(r"USING (COVERING )?INDEX (samples|events)_time", p)
                   for p in plan if p.startswith(("SCAN s", "SEARCH s", "SCAN e", "SEARCH e"))
                   ), (q, plan)
        assert any("_time" in p for p in plan), (q, plan)
        # and Debian's own sqlite3 runs them as written
        out = subprocess.run(["sqlite3", str(db), q], capture_output=True, text=True,
                             timeout=60, check=True)
        assert out.stdout.strip(), q
    con.close()


def test_a_database_of_the_old_format_is_exported_and_never_mixed(tmp_path: Path) -> None:
    db = tmp_path / "old.sqlite"
    rng = random.Random(5)
    readings = [(T0 + i, decode_hub(random_registers(rng))) for i in range(3)]
    write_format1(str(db), readings)
    before = db.read_bytes()
    with pytest.raises(InvalidArgument, match=r"format 1.*new file.*export"):
        SqliteSink(db)
    assert db.read_bytes() == before  # untouched
    out = run_pymb("log", "--port", str(tmp_path / "no-such-port"),
                   "--device", "hub", "--out", str(db), "--seconds", "1", timeout=60)
    assert out.returncode == 2, out.stderr
    assert "format 1" in out.stderr
    assert "Traceback" not in out.stderr
    assert db.read_bytes() == before
    import io

    buf = io.StringIO()
    assert export_csv(str(db), buf) == 3 * 100 * 7
    lines = buf.getvalue().splitlines()
    assert lines[1].split(",")[6:8] == ["1", "temperature_c"]


def test_export_reads_format_2_as_it_read_format_1(tmp_path: Path) -> None:
    """The same readings give the same CSV from either format."""
    import io

    rng = random.Random(9)
    readings = [(T0 + i, decode_hub(random_registers(rng))) for i in range(3)]
    old, new = tmp_path / "old.sqlite", tmp_path / "new.sqlite"
    write_format1(str(old), readings)
    sink = SqliteSink(new)
    for t, r in readings:
        sink.write(Sample(DeviceInfo("bus1", "/dev/null", "hub", 1, "hub-1"), t, t, r))
    sink.close()
    a, b = io.StringIO(), io.StringIO()
    export_csv(str(old), a)
    export_csv(str(new), b)
    assert a.getvalue() == b.getvalue()


def test_a_file_that_is_not_pymbs_is_refused(tmp_path: Path) -> None:
    db = tmp_path / "other.sqlite"
    con = sqlite3.connect(db)
    con.execute("CREATE TABLE t(x)")
    con.commit()
    con.close()
    with pytest.raises(InvalidArgument, match="not a pymb database"):
        SqliteSink(db)


def _sweep(temps: dict[int, int], offline: tuple[int, ...] = ()) -> array[int]:
    regs = array("H", [200] * HUB_REGISTERS)  # 20.0 °C, 20.0 %, ... everywhere
    for ch, tenths in temps.items():
        regs[ch - 1] = tenths
    for ch in offline:
        for b in range(len(BLOCKS)):
            regs[b * CHANNELS + ch - 1] = 0xFFFF
    return regs


def test_on_change_stores_moves_past_the_deadband_states_and_heartbeats(tmp_path: Path) -> None:
    db = tmp_path / "oc.sqlite"
    sink = SqliteSink(db, on_change=OnChange(10.0, {"temperature_c": 1.0}))
    hub = DeviceInfo("b", "p", "hub", 1, "hub-1")
    steps = [
        (0.0, _sweep({})),                 # first: every channel
        (1.0, _sweep({3: 205})),           # +0.5 °C: within the deadband
        (2.0, _sweep({3: 211})),           # +1.1 °C since stored: stored
        (3.0, _sweep({3: 211}, (5,))),     # channel 5 goes offline: stored
        (4.0, _sweep({3: 211}, (5,))),     # nothing new
        (12.0, _sweep({3: 211}, (5,))),    # heartbeat: every channel again
    ]
    for mono, regs in steps:
        sink.write(Sample(hub, T0 + mono, mono, decode_hub(regs)))
    sink.close()
    con = sqlite3.connect(db)
    per_sample = con.execute("SELECT s.id, COUNT(x.channel) FROM samples s LEFT JOIN "
                             "hub_changes x ON x.sample_id = s.id GROUP BY s.id").fetchall()
    assert [n for _, n in per_sample] == [100, 1, 1, 99]  # 5's heartbeat is at 13

    def at(t: float, ch: int) -> tuple[float | None, int]:
        row: tuple[float | None, int] = con.execute(
            "SELECT temperature_c, temperature_c_state FROM hub_readings WHERE device = "
            "'hub-1' AND channel = ? AND time_utc <= ? ORDER BY time_utc DESC LIMIT 1",
            (ch, T0 + t)).fetchone()
        return row

    assert at(1.5, 3) == (20.0, 0)  # the 20.5 was within the deadband: 20.0 stands
    assert at(2.5, 3) == (21.1, 0)
    assert at(3.5, 5) == (None, 1)  # offline
    assert at(3.5, 4) == (20.0, 0)  # stored at t=0, unchanged since
    assert at(12.0, 4) == (20.0, 0)
    con.close()
    s = samples_after(db, 1, 1)[0]  # the second stored sample: channel 3 only
    assert isinstance(s.data, HubReading)
    assert s.data.as_dict()["temperature_c"][2] == 21.1
    assert s.data.state("temperature_c", 1) is State.NOT_READ
    assert s.data.as_dict()["temperature_c"][0] is None


def test_outbox_cursor_trimming_records_what_was_never_sent(tmp_path: Path) -> None:
    db = tmp_path / "fwd.sqlite"
    sink = SqliteSink(db, max_bytes=1_000_000)
    sink.db.execute("CREATE TABLE outbox(name TEXT PRIMARY KEY, sample_id INTEGER)")
    sink.db.execute("INSERT INTO outbox VALUES ('mqtt', 10)")
    hub = DeviceInfo("b", "p", "hub", 1, "hub-1")
    r = decode_hub(array("H", range(700)))
    now = time.time()
    for i in range(1200):
        sink.write(Sample(hub, now - 1200 + i, float(i), r))
        if i % 20 == 19:
            sink.commit()
    sink.close()
    con = sqlite3.connect(db)
    first = con.execute("SELECT MIN(id) FROM samples").fetchone()[0]
    assert first > 11
    events = con.execute("SELECT code, message FROM events WHERE kind = 'trim' "
                         "ORDER BY id").fetchall()
    assert events
    assert "not yet forwarded" in events[0][1]
    # every deleted sample after the cursor is counted, once
    assert sum(code for code, _ in events) == first - 11
    con.close()


def test_the_size_bound_holds_for_the_file_and_its_wal_at_full_speed(tmp_path: Path) -> None:
    db = tmp_path / "bound.sqlite"
    limit = 4_000_000
    sink = SqliteSink(db, max_bytes=limit)
    hub = DeviceInfo("b", "p", "hub", 1, "hub-1")
    cp = DeviceInfo("b", "p", "coolpro", 40, "cp")
    from pymb.devices import CoolProStatus, CoolProTelemetry

    rng = random.Random(1)
    t = CoolProTelemetry(1, 1, 1, 1, 1, 1, CoolProStatus(0), array("H", range(8)))
    worst = 0
    wal = Path(f"{db}-wal")
    for i in range(6000):  # about 10 MB unbounded, as fast as Python writes
        sink.write(Sample(hub, T0 + i, float(i), decode_hub(random_registers(rng))))
        sink.write(Sample(cp, T0 + i, float(i), t))
        if i % 8 == 7:
            sink.commit()
            worst = max(worst, db.stat().st_size + (wal.stat().st_size if wal.exists() else 0))
    sink.close()
    assert sink.trimmed > 0
    assert worst <= 1.1 * limit, worst


@pytest.mark.parametrize(("flag", "value"), [("--max-mb", "-5"), ("--max-mb", "0"),
                                              ("--max-age-days", "-1"), ("--max-mb", "nan")])
def test_limits_that_are_not_positive_are_refused(tmp_path: Path, flag: str, value: str) -> None:
    out = run_pymb("log", "--port", str(tmp_path / "p"), "--device", "hub",
                   "--out", str(tmp_path / "x.sqlite"), flag, value, "--seconds", "1", timeout=60)
    assert out.returncode == 2
    assert "positive" in out.stderr
    assert "Traceback" not in out.stderr
    assert not (tmp_path / "x.sqlite").exists()


def test_limits_in_toml_that_are_not_positive_are_refused(tmp_path: Path) -> None:
    from pymb.logger import load_config

    cfg = tmp_path / "c.toml"
    cfg.write_text('[output]\nmax_mb = -5\n[[bus]]\nport = "/dev/x"\n'
                   '[[bus.device]]\ntype = "hub"\naddress = 1\n')
    with pytest.raises(InvalidArgument, match="positive"):
        load_config(cfg)


def test_pymb_log_on_change_end_to_end(tmp_path: Path) -> None:
    """``pymb log --on-change`` against a simulated hub whose values drift slowly
    (each sensor reports every 2 s): far fewer rows, every channel queryable."""

    from pymb.sim import Simulator

    db = tmp_path / "oc.sqlite"
    with Simulator(["hub:250"], seed=3) as sim:
        r = run_pymb("log", "--port", sim.port, "--device", "hub:250",
                     "--on-change", "--deadband", "temperature_c=0.5", "--heartbeat", "30",
                     "--seconds", "3", "--out", str(db), "--timeout", "1", timeout=120)
    assert r.returncode == 0, r.stderr
    m = re.search(r"logged ([\d,]+) samples", r.stderr)
    assert m, r.stderr
    read = int(m.group(1).replace(",", ""))
    con = sqlite3.connect(db)
    stored = con.execute("SELECT COUNT(*) FROM samples").fetchone()[0]
    rows = con.execute("SELECT COUNT(*) FROM hub_changes").fetchone()[0]
    assert read >= 2
    assert 1 <= stored <= read
    assert 100 <= rows < 100 * read  # the first sweep whole, then only what moved
    for ch in (1, 50, 100):
        row = con.execute(
            "SELECT temperature_c_state FROM hub_readings WHERE device = 'hub-250' AND "
            "channel = ? AND time_utc <= unixepoch('now') + 1 ORDER BY time_utc DESC LIMIT 1",
            (ch,)).fetchone()
        assert row is not None
    con.close()
    bad = run_pymb("log", "--port", "/dev/null", "--device", "hub", "--deadband",
                   "temperature_c=0.5", "--out", str(tmp_path / "y.sqlite"), timeout=60)
    assert bad.returncode == 2
    assert "--on-change" in bad.stderr


def test_a_size_limit_below_one_megabyte_is_refused(tmp_path: Path) -> None:
    out = run_pymb("log", "--port", str(tmp_path / "p"), "--device", "hub", "--out",
                   str(tmp_path / "x.sqlite"), "--max-mb", "0.5", "--seconds", "1", timeout=60)
    assert out.returncode == 2
    assert "at least 1 MB" in out.stderr


def test_a_new_humidity_unit_is_a_new_device_row_and_old_samples_keep_theirs(
        tmp_path: Path) -> None:
    db = tmp_path / "units.sqlite"
    regs = array("H", [200] * HUB_REGISTERS)  # humidity register 200: 20.0 % or 200 %
    for unit in (0.1, 1):
        sink = SqliteSink(db)
        dev = DeviceInfo("b", "p", "hub", 1, "hub-1", 100, unit)
        sink.write(Sample(dev, T0 + unit, 0.0, decode_hub(regs, unit)))
        sink.close()
    con = sqlite3.connect(db)
    assert con.execute("SELECT COUNT(*) FROM devices").fetchone()[0] == 2
    got = con.execute("SELECT humidity_pct FROM hub_readings WHERE channel = 1 "
                      "ORDER BY time_utc").fetchall()
    assert got == [(20.0,), (200.0,)]
    con.close()


def test_on_change_in_toml(tmp_path: Path) -> None:
    from pymb.logger import load_config

    cfg = tmp_path / "c.toml"
    cfg.write_text('[output]\non_change = true\nheartbeat_s = 30\n'
                   'deadband = { temperature_c = 0.2, humidity_pct = 1 }\n'
                   '[[bus]]\nport = "/dev/x"\n[[bus.device]]\ntype = "hub"\naddress = 1\n')
    c = load_config(cfg)
    assert c.on_change == OnChange(30.0, {"temperature_c": 0.2, "humidity_pct": 1.0})
    cfg.write_text('[output]\non_change = true\ndeadband = { temprature_c = 0.2 }\n'
                   '[[bus]]\nport = "/dev/x"\n[[bus.device]]\ntype = "hub"\naddress = 1\n')
    with pytest.raises(InvalidArgument, match="temprature_c"):
        load_config(cfg)


def test_pymb_log_max_mb_holds_file_plus_wal_flat_out(tmp_path: Path) -> None:
    """``--max-mb`` at full speed, watched from outside while
    ``pymb log`` runs: the database file and its WAL stay within 10 %."""

    from pymb.bench.procs import Children

    db = tmp_path / "bound.sqlite"
    wal = Path(f"{db}-wal")
    with Children() as ch:
        (sim,) = ch.sims([["hub:1,dynamic=0,baud=115200"]])  # no wire emulation: flat out
        p = subprocess.Popen(
            [*PYMB, "log", "--port", sim.port, "--baud", "115200",
             "--device", "hub", "--max-mb", "2", "--seconds", "6", "--quiet", "--out", str(db)],
            env=PYMB_ENV, stderr=subprocess.PIPE, text=True)
        worst = 0
        deadline = time.monotonic() + 60
        while p.poll() is None and time.monotonic() < deadline:
            size = sum(f.stat().st_size for f in (db, wal) if f.exists())
            worst = max(worst, size)
            time.sleep(0.02)
        _, err = p.communicate(timeout=30)
    assert p.returncode == 0, err
    con = sqlite3.connect(db)
    stored = con.execute("SELECT COUNT(*) FROM samples").fetchone()[0]
    first = con.execute("SELECT MIN(id) FROM samples").fetchone()[0]
    con.close()
    assert first > 1, "the run never reached the bound: nothing was trimmed"
    assert worst <= 1.1 * 2_000_000, worst
    assert stored * 1400 < 2_000_000


def test_registers_are_stored_big_endian_and_read_back() -> None:
    """A sample's registers are stored as they travel (big-endian 16-bit
    words, whatever this machine's byte order) and read back as registers."""
    regs = array("H", [0x1234, 0xFFFF, 0x0001])
    blob = wire_bytes(regs)
    assert blob == b"\x12\x34\xff\xff\x00\x01"
    assert regs == array("H", [0x1234, 0xFFFF, 0x0001])  # the caller's array is left alone
    assert host_words(blob) == regs
