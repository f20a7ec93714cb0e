"""Map devices through ``pymb log``, end to end: ``pymb simulate --map``
serving them over TCP, ``pymb log`` (command line and TOML) writing a real
SQLite file, and what was stored read back (samples, export)."""

from __future__ import annotations

import csv
import io
import sqlite3
from pathlib import Path

import pytest
from conftest import run_pymb

from pymb import maps
from pymb.devices.mapreading import MapReading
from pymb.sim import SimulatorProcess
from pymb.store import samples_after

TEST_MAP = '''schema = "pymb.map/1"
[device]
id = "test-meter"
table = "input"
[device.timing]
offline_after = 2
offline_retry = 1.0
[[point]]
name = "voltage_v"
address = 0
type = "f32"
unit = "V"
example = 230.5
[[point]]
name = "energy_kwh"
address = 2
type = "u32"
kind = "counter"
example = 1234
'''


def _counts(db: Path) -> dict[tuple[str, str], int]:
    con = sqlite3.connect(db)
    try:
        return {(name, units): n for name, units, n in con.execute(
            "SELECT d.name, d.humidity_units, count(*) FROM samples s JOIN devices d "
            "ON d.id = s.device_id GROUP BY d.id")}
    finally:
        con.close()


def test_shipped_maps_log_by_group_and_read_back(tmp_path: Path) -> None:
    db = tmp_path / "maps.sqlite"
    with SimulatorProcess(["eastron-sdm120:3", "generic-vfd:5", "--tcp", "127.0.0.1:0"],
                          quiet=True) as sim:
        r = run_pymb("log", "--tcp", sim.endpoint, "eastron-sdm120:3", "generic-vfd:5",
                     "--seconds", "2.5", "--out", str(db), "--quiet")
    assert r.returncode == 0, r.stderr
    counts = _counts(db)
    # fast (1 s): at 0, 1, 2 s; energy (10 s): once; config (interval 0): once a connection
    assert 3 <= counts[("eastron-sdm120-3", "group=fast")] <= 4, counts
    assert counts[("eastron-sdm120-3", "group=energy")] == 1, counts
    assert counts[("eastron-sdm120-3", "group=config")] == 1, counts
    assert counts[("generic-vfd-5", "group=settings")] == 1, counts
    m = maps.builtin("eastron-sdm120")
    seen = set()
    for s in samples_after(db, 0, limit=100):
        assert isinstance(s.data, MapReading)
        if s.device.type != "eastron-sdm120":
            continue
        seen.add(s.data.group)
        for name, v in s.data.values.items():
            p = m.points[name]
            assert p.group == s.data.group
            if isinstance(p.example, float):
                assert v == pytest.approx(p.example, rel=1e-6), name
            assert s.data.states[name] == "value", name
    assert seen == {"fast", "energy", "config"}
    # the group's registers once: voltage_v (f32 at 0) .. the fast group's last point
    con = sqlite3.connect(db)
    (size,) = con.execute("SELECT length(registers) FROM samples s JOIN devices d ON "
                          "d.id = s.device_id WHERE d.humidity_units = 'group=fast' "
                          "AND d.type = 'eastron-sdm120' LIMIT 1").fetchone()
    con.close()
    fast = [p for p in m.points.values() if p.group == "fast"]
    assert size == 2 * (max(p.end for p in fast) - min(p.address for p in fast))
    long = run_pymb("export", str(db), "--csv", "-")
    assert long.returncode == 0, long.stderr
    rows = list(csv.DictReader(io.StringIO(long.stdout)))
    volts = [r for r in rows if r["quantity"] == "voltage_v"]
    assert volts
    assert all(float(r["value"]) == 230.5 and r["state"] == "value" for r in volts)
    wide = run_pymb("export", str(db), "--csv", "-", "--layout", "wide")
    assert wide.returncode == 0, wide.stderr
    table = list(csv.DictReader(io.StringIO(wide.stdout)))
    assert "voltage_v" in table[0]
    assert "frequency_hz" in table[0]
    assert any(r["voltage_v"] == "230.5" for r in table)


def test_toml_maps_groups_and_a_map_file(tmp_path: Path) -> None:
    (tmp_path / "meter.toml").write_text(TEST_MAP)
    db = tmp_path / "t.sqlite"
    config = tmp_path / "log.toml"
    config.write_text(f'''maps = ["meter.toml"]
[output]
path = "{db}"
[[bus]]
tcp = "ENDPOINT"
[[bus.device]]
type = "test-meter"
address = 1
[[bus.device]]
type = "eastron-sdm120"
address = 2
groups = ["energy"]
''')
    with SimulatorProcess(["--map", str(tmp_path / "meter.toml"), "test-meter:1",
                           "eastron-sdm120:2", "--tcp", "127.0.0.1:0"], quiet=True) as sim:
        config.write_text(config.read_text().replace("ENDPOINT", sim.endpoint))
        r = run_pymb("log", "--config", str(config), "--seconds", "1", "--quiet")
    assert r.returncode == 0, r.stderr
    counts = _counts(db)
    assert set(counts) == {("test-meter-1", "group="), ("eastron-sdm120-2", "group=energy")}
    assert counts[("test-meter-1", "group=")] > 10  # no groups: every point, flat out
    got = samples_after(db, 0, limit=1)[0]
    assert isinstance(got.data, MapReading)
    assert got.data.values == {"voltage_v": 230.5, "energy_kwh": 1234}


@pytest.mark.parametrize(("device", "says"), [
    ('type = "eastron-sdm12"', "device 1: unknown type 'eastron-sdm12'; did you mean "
                               "'eastron-sdm120'?"),
    ('type = "eastron-sdm120"\ngroups = ["fats"]', "groups: eastron-sdm120 has no group "
                                                   "'fats'; did you mean 'fast'?"),
    ('type = "eastron-sdm120"\ngrups = ["fast"]', "unknown key 'grups' for eastron-sdm120; "
                                                  "did you mean 'groups'?"),
    ('map = "missing.toml"', "device 1: map: cannot read the map"),
    ('type = "eastron-sdm120"\nchanels = 5', "unknown key 'chanels' for eastron-sdm120"),
    ('type = "eastron-sdm120"\ndeadband = { voltage = 1 }', "deadband: eastron-sdm120 has "
                                                            "no point 'voltage'"),
    ('type = "eastron-sdm120"\noffline_retry = 0', "offline_retry must be a number of "
                                                   "seconds above 0"),
])
def test_a_mistake_is_one_line_naming_file_and_key(tmp_path: Path, device: str,
                                                   says: str) -> None:
    config = tmp_path / "bad.toml"
    config.write_text(f'[[bus]]\ntcp = "127.0.0.1:1"\n[[bus.device]]\n{device}\n')
    r = run_pymb("log", "--config", str(config), "--seconds", "1")
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    assert str(config) in lines[0], r.stderr
    assert says in lines[0], r.stderr


def test_map_on_the_command_line(tmp_path: Path) -> None:
    (tmp_path / "meter.toml").write_text(TEST_MAP)
    r = run_pymb("log", "--tcp", "127.0.0.1:1", "test-meter:1", "--seconds", "1")
    assert r.returncode == 2, r.stderr
    assert "unknown device 'test-meter:1'" in r.stderr
    db = tmp_path / "cli.sqlite"
    with SimulatorProcess(["--map", str(tmp_path / "meter.toml"), "test-meter:4",
                           "--tcp", "127.0.0.1:0"], quiet=True) as sim:
        r = run_pymb("log", "--map", str(tmp_path / "meter.toml"), "--tcp", sim.endpoint,
                     "test-meter:4,name=main", "--seconds", "0.5", "--out", str(db), "--quiet")
    assert r.returncode == 0, r.stderr
    assert _counts(db)[("main", "group=")] > 0


def test_a_silent_unit_costs_one_timeout_per_retry_period(tmp_path: Path) -> None:
    """Three units on one TCP gateway, unit 3 silent: with offline_after 2
    and offline_retry 1 s (the map's timing), it is asked at most twice and
    then once a second, and the live units go on being read."""
    (tmp_path / "meter.toml").write_text(TEST_MAP)
    db = tmp_path / "h.sqlite"
    config = tmp_path / "h.toml"
    with SimulatorProcess(["--map", str(tmp_path / "meter.toml"), "test-meter:1",
                           "test-meter:2", "--tcp", "127.0.0.1:0"], quiet=True) as sim:
        config.write_text(f'''maps = ["meter.toml"]
[output]
path = "{db}"
[[bus]]
tcp = "{sim.endpoint}"
timeout = 0.2
''' + "".join(f'[[bus.device]]\ntype = "test-meter"\naddress = {a}\n' for a in (1, 2, 3)))
        r = run_pymb("log", "--config", str(config), "--seconds", "3")
    assert r.returncode == 3, r.stderr  # unit 3 delivered nothing
    con = sqlite3.connect(db)
    timeouts = con.execute("SELECT count(*) FROM events e JOIN devices d ON d.id = e.device_id "
                           "WHERE d.name = 'test-meter-3' AND e.kind = 'timeout'").fetchone()[0]
    offline = con.execute("SELECT count(*) FROM events WHERE message LIKE "
                          "'%offline after 2 failed poll(s), next try in 1 s'").fetchone()[0]
    con.close()
    # 2 before it is offline, then one a second over 3 s (the first retry
    # comes 1 s after the second timeout)
    assert 2 <= timeouts <= 5, timeouts
    assert offline == 1
    counts = _counts(db)
    assert counts[("test-meter-1", "group=")] > 50
    assert counts[("test-meter-2", "group=")] > 50
    assert "test-meter-3 delivered no sample: no reply (timeout)" in r.stderr
    # counted per device in the summary, and named in the final status line
    assert f"\ntest-meter-3: {timeouts} failed poll(s), 0 sample(s)\n" in r.stderr, r.stderr
    assert "failing 1: test-meter-3" in r.stderr, r.stderr


def test_the_summary_of_a_forwarding_run_counts_a_failing_device_too(tmp_path: Path) -> None:
    """``pymb log --mqtt`` (the broker not reachable: the samples wait in the
    file) has the same line per failing device in its summary."""
    import socket

    (tmp_path / "meter.toml").write_text(TEST_MAP)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        closed = s.getsockname()[1]
    with SimulatorProcess(["--map", str(tmp_path / "meter.toml"), "test-meter:1",
                           "--tcp", "127.0.0.1:0"], quiet=True) as sim:
        r = run_pymb("log", "--map", str(tmp_path / "meter.toml"), "--tcp", sim.endpoint,
                     "test-meter:1", "test-meter:2", "--timeout", "0.2", "--seconds", "2",
                     "--out", str(tmp_path / "f.sqlite"),
                     "--mqtt", f"mqtt://127.0.0.1:{closed}")
    assert r.returncode == 3, r.stderr  # unit 2 delivered nothing
    assert "\ntest-meter-2: " in r.stderr, r.stderr
    assert " failed poll(s), 0 sample(s)\n" in r.stderr, r.stderr


def test_a_point_the_device_refuses_is_unsupported_and_counted(tmp_path: Path) -> None:
    """The logger's map has a point the device lacks (it answers exception
    02): the point reads None with the state unsupported, the others are
    stored, and the summary counts it."""
    (tmp_path / "served.toml").write_text(TEST_MAP)
    (tmp_path / "meter.toml").write_text(TEST_MAP + '''[[point]]
name = "missing_a"
address = 100
type = "f32"
''')
    db = tmp_path / "u.sqlite"
    with SimulatorProcess(["--map", str(tmp_path / "served.toml"), "test-meter:1",
                           "--tcp", "127.0.0.1:0"], quiet=True) as sim:
        r = run_pymb("log", "--map", str(tmp_path / "meter.toml"), "--tcp", sim.endpoint,
                     "test-meter:1", "--seconds", "0.5", "--out", str(db))
    assert r.returncode == 0, r.stderr
    got = samples_after(db, 0, limit=1_000_000)
    assert got
    for s in got:
        assert isinstance(s.data, MapReading)
        assert s.data.values["missing_a"] is None
        assert s.data.states["missing_a"] == "unsupported"
        assert s.data.values["voltage_v"] == 230.5
    assert len(got) > 1
    # one point refused, however many polls refused it
    assert f"test-meter-1: 1 point(s) unsupported, {len(got)} sample(s)" in r.stderr


def test_on_change_with_a_map_device(tmp_path: Path) -> None:
    """--on-change with a map device read flat out: values that never move
    are stored once and then at each heartbeat, not at every poll."""
    (tmp_path / "meter.toml").write_text(TEST_MAP)
    db = tmp_path / "oc.sqlite"
    with SimulatorProcess(["--map", str(tmp_path / "meter.toml"), "test-meter:1",
                           "--tcp", "127.0.0.1:0"], quiet=True) as sim:
        r = run_pymb("log", "--map", str(tmp_path / "meter.toml"), "--tcp", sim.endpoint,
                     "test-meter:1", "--on-change", "--heartbeat", "1", "--seconds", "2.5",
                     "--out", str(db))
    assert r.returncode == 0, r.stderr
    polled = int(r.stderr.split("logged ")[1].split(" samples")[0].replace(",", ""))
    stored = _counts(db)[("test-meter-1", "group=")]
    assert polled > 100
    assert 2 <= stored <= 4, (polled, stored)  # at 0, 1 and 2 s


def _rate_of_live_units(tmp_path: Path, meter: Path, endpoint: str, units: tuple[int, ...],
                        name: str) -> float:
    db = tmp_path / f"{name}.sqlite"
    config = tmp_path / f"{name}.toml"
    config.write_text(f'''maps = ["{meter}"]
[output]
path = "{db}"
[[bus]]
tcp = "{endpoint}"
timeout = 0.1
''' + "".join(f'[[bus.device]]\ntype = "test-meter"\naddress = {a}\noffline_after = 1\n'
              f'offline_retry = 5\n' for a in units))
    r = run_pymb("log", "--config", str(config), "--seconds", "6", "--quiet")
    assert r.returncode in (0, 3), r.stderr
    counts = _counts(db)
    return (counts[("test-meter-1", "group=")] + counts[("test-meter-2", "group=")]) / 6.0


@pytest.mark.timing
def test_the_live_units_keep_their_rate_beside_a_silent_one(tmp_path: Path) -> None:
    """Two live units alone, then with a silent third on the same gateway
    (offline_after 1, offline_retry 5 s, 0.1 s timeout): the live units' rate
    stays within 10 % of their rate alone."""
    meter = tmp_path / "meter.toml"
    meter.write_text(TEST_MAP)
    with SimulatorProcess(["--map", str(meter), "test-meter:1", "test-meter:2",
                           "--tcp", "127.0.0.1:0"], quiet=True) as sim:
        alone = _rate_of_live_units(tmp_path, meter, sim.endpoint, (1, 2), "alone")
        beside = _rate_of_live_units(tmp_path, meter, sim.endpoint, (1, 2, 3), "beside")
    print(f"\nlive units: {alone:,.0f} samples/s alone, {beside:,.0f} beside a silent unit")
    assert beside >= 0.9 * alone, (alone, beside)
