"""The map command line with real processes: ``pymb map check``, ``pymb map
probe``, ``--map`` on read, watch, scan and simulate, ``pymb simulate --map``
over a pty and TCP with its fault injectors; every mistake a one-line error."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from conftest import run_pymb

import pymb
from pymb import maps
from pymb.devices import MapDevice
from pymb.sim import SimulatorProcess

METER = """schema = "pymb.map/1"

[device]
id = "acme-meter"
manufacturer = "ACME"
model = "M-1"
default_address = 3
table = "input"

[device.options]
phases = { default = 3, values = [1, 3] }

[device.limits]
max_gap = 4

[device.timing]
turnaround = 0.01

[groups]
fast = { interval = 1.0 }

[[point]]
name = "voltage_v"
address = 0
type = "f32"
unit = "V"
example = 230.5
group = "fast"

[[point]]
name = "current_a"
address = 6
type = "f32"
unit = "A"
example = 4.25
group = "fast"

[[point]]
name = "mode"
table = "holding"
address = 0
type = "u16"
access = "rw"
values = { 0 = "auto", 1 = "manual" }
example = 1

[[point]]
name = "model_name"
table = "holding"
address = 100
type = "string"
count = 4
example = "M-1"

[[identify]]
point = "voltage_v"
range = [80.0, 300.0]
"""


@pytest.fixture
def meter(tmp_path: Path) -> Path:
    path = tmp_path / "meter.toml"
    path.write_text(METER)
    return path


def one_line_error(r: object, *words: str) -> None:
    rc, out, err = r.returncode, r.stdout, r.stderr  # type: ignore[attr-defined]
    assert rc == 2, (out, err)
    assert "Traceback" not in err
    assert len(err.strip().splitlines()) == 1, err
    for w in words:
        assert w in err, err


def test_map_check_prints_each_groups_plan_and_wire_time(meter: Path) -> None:
    r = run_pymb("map", "check", str(meter), "--baud", "19200")
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert lines[0] == f"{meter}: acme-meter (ACME M-1): 4 points, 1 group: valid"
    assert "group fast: 2 points, every 1 s" in lines
    # the two floats 0..1 and 6..7: the 4-register gap is bridged (max_gap = 4)
    # because one request costs less than two at 19200 with a 10 ms turnaround
    m = maps.load(meter)
    plan = m.plan("fast", baudrate=19200)
    assert plan.spans == ((0, 8),)
    assert "      1. input registers 0..7 (8)" in r.stdout
    assert f"predicted {plan.predicted_s * 1e3:.2f} ms" in r.stdout
    assert "group (none): 2 points, read on request" in lines
    r = run_pymb("map", "check", "hub")  # a shipped map, by its id
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith("hub: hub (100-channel sensor hub): 7 points, 1 group: valid")
    assert "6 request(s), 700 registers on the wire" in r.stdout


def test_map_check_counts_coil_and_input_bits_as_bits(tmp_path: Path) -> None:
    f = tmp_path / "relays.toml"
    f.write_text('schema = "pymb.map/1"\n[device]\nid = "relays"\nmanufacturer = "M"\n'
                 'model = "R"\n[groups]\nbits = { interval = 1.0 }\n'
                 'words = { interval = 1.0 }\n'
                 + "".join(f'[[point]]\nname = "{n}"\ntable = "{t}"\naddress = {a}\n'
                           f'type = "{ty}"\ngroup = "{g}"\n'
                           for n, t, a, ty, g in [("relay", "coil", 0, "bool", "bits"),
                                                  ("alarm", "discrete", 3, "bool", "bits"),
                                                  ("volts", "holding", 0, "u16", "words"),
                                                  ("amps", "holding", 1, "u16", "words")]))
    r = run_pymb("map", "check", str(f))
    assert r.returncode == 0, r.stderr
    assert "2 request(s), 2 bits on the wire for 2 point(s)" in r.stdout
    assert "1 request(s), 2 registers on the wire for 2 point(s)" in r.stdout
    plan = maps.load(f).plan("bits")
    first = plan.explain().split("\n")[0]
    assert first.endswith("2 bits on the wire for 2 point(s)")
    assert "registers" not in first


def test_map_check_says_how_each_group_is_polled() -> None:
    # a group's ``poll`` says when the logger reads it: at its bus's interval
    # (not its own), or never (read on request, pymb read --group)
    r = run_pymb("map", "check", "coolpro")
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert "group telemetry: 7 points, at the bus's interval" in lines
    assert "group identity: 6 points, read on request" in lines
    assert "group config: 3 points, read on request" in lines
    r = run_pymb("map", "check", "hub")
    assert "group sweep: 7 points, at the bus's interval" in r.stdout.splitlines()


def test_map_check_mistakes_are_one_line(tmp_path: Path, meter: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text(METER.replace('unit = "A"', 'unti = "A"'))
    one_line_error(run_pymb("map", "check", str(bad)), "bad.toml", "current_a", "unti",
                   "did you mean 'unit'")
    one_line_error(run_pymb("map", "check", str(tmp_path / "none.toml")), "none.toml")
    one_line_error(run_pymb("map"), "pymb map check FILE")


def test_simulate_read_watch_probe_and_scan_a_map_over_a_pty(meter: Path) -> None:
    with SimulatorProcess(["--map", str(meter), "acme-meter:3"], quiet=True) as sim:
        r = run_pymb("read", "--map", str(meter), "acme-meter:3", "--port", sim.port, "--json")
        assert r.returncode == 0, r.stderr
        doc = json.loads(r.stdout)
        assert doc["device"] == "acme-meter"
        assert doc["address"] == 3
        assert doc["values"] == {"voltage_v": 230.5, "current_a": 4.25, "mode": 1,
                                 "model_name": "M-1"}
        assert set(doc["states"].values()) == {"value"}
        r = run_pymb("read", "--map", str(meter), "acme-meter", "--group", "fast",
                     "--port", sim.port)
        assert r.returncode == 0, r.stderr
        assert r.stdout.split("\n") == ["voltage_v  230.5 V", "current_a  4.25 A", ""]
        r = run_pymb("read", "--map", str(meter), "acme-meter", "--group", "fast",
                     "--identity", "--port", sim.port)
        assert r.returncode == 0, r.stderr
        assert r.stdout.splitlines()[-1] == "Identity         ACME M-1 (voltage_v 230.5)"
        r = run_pymb("watch", "--map", str(meter), "acme-meter:3", "--port", sim.port,
                     "--count", "2", "--json")
        assert r.returncode == 0, r.stderr
        frames = [json.loads(line) for line in r.stdout.splitlines()]
        assert [f["attempt"] for f in frames] == [1, 2]
        assert all(f["values"]["voltage_v"] == 230.5 for f in frames)
        r = run_pymb("map", "probe", "--port", sim.port, "3", "input:0:2")
        assert r.returncode == 0, r.stderr
        abcd = next(line for line in r.stdout.splitlines() if line.strip().startswith("ABCD"))
        assert abcd.split()[-1] == "230.5"
        cdab = next(line for line in r.stdout.splitlines() if line.strip().startswith("CDAB"))
        assert cdab.split()[-1] != "230.5"
        r = run_pymb("map", "probe", "--port", sim.port, "3", "i:0:2", "--json")
        assert r.returncode == 0, r.stderr
        doc = json.loads(r.stdout)
        assert doc["registers"] == [0x4366, 0x8000]
        assert doc["rows"][0]["f32_ABCD"] == 230.5
        assert doc["rows"][0]["u16_AB"] == 0x4366
        assert doc["rows"][1]["u16_BA"] == 0x0080
        r = run_pymb("scan", "--port", sim.port, "--range", "1-4", "--map", str(meter))
        assert r.returncode == 0, r.stderr
        assert r.stdout.split()[:2] == ["3", "acme-meter"]
        assert "voltage_v 230.5" in r.stdout


def test_simulate_a_map_over_tcp_with_faults(meter: Path) -> None:
    args = ["--map", str(meter), "acme-meter:7", "--tcp", "127.0.0.1:0", "--seed", "3"]
    with SimulatorProcess([*args, "--fault", "sensor:1,seconds=60"], quiet=True) as sim, \
            pymb.TcpClient(sim.host, sim.tcp_port, timeout=2.0) as client:
        dev = MapDevice(client, maps.load(meter), 7)
        got = dev.read("voltage_v", "current_a")
        # a float point's sensor fault is its NaN: no value, named
        assert None in got.values()
        assert "nan" in dev.states.values()
    with SimulatorProcess([*args, "--fault", "busy:1"], quiet=True) as sim:
        r = run_pymb("read", "--map", str(meter), "acme-meter:7", "--tcp", sim.endpoint)
        assert r.returncode == 3
        assert "Traceback" not in r.stderr
        assert "exception 04" in r.stderr.lower() or "failure" in r.stderr.lower(), r.stderr


def test_a_map_device_refuses_what_it_does_not_declare(meter: Path) -> None:
    with SimulatorProcess(["--map", str(meter), "acme-meter:3"], quiet=True) as sim, \
            pymb.RtuClient(sim.port, 9600, timeout=2.0) as client:
        with pytest.raises(pymb.IllegalDataAddress):
            client.read_input_registers(0, 3, slave=3)  # 2 is not declared
        assert list(client.read_input_registers(0, 2, slave=3)) == [0x4366, 0x8000]
        dev = MapDevice(client, maps.load(meter), 3)
        dev.write("mode", "auto")
        assert dev.read("mode") == {"mode": 0}
        with pytest.raises(pymb.InvalidArgument, match="not one of its values"):
            dev.write("mode", "off")


def test_device_syntax_mistakes_are_one_line(meter: Path) -> None:
    m = str(meter)
    one_line_error(run_pymb("read", "--map", m, "acme-meter:3,phase=1", "--port", "/dev/null"),
                   "unknown key 'phase'", "did you mean 'phases'")
    one_line_error(run_pymb("read", "--map", m, "acme-meter:3,phases=2", "--port", "/dev/null"),
                   "phases")
    one_line_error(run_pymb("read", "--map", m, "acme-meter:300", "--port", "/dev/null"),
                   "address must be")
    one_line_error(run_pymb("read", "acme-meter:3", "--port", "/dev/null"),
                   "unknown device", "--map FILE")
    one_line_error(run_pymb("read", "--map", m, "acme-meter", "--group", "slwo",
                            "--port", "/dev/null"), "no group 'slwo'")
    one_line_error(run_pymb("simulate", "--map", m, "acme-metre:3"),
                   "did you mean 'acme-meter'")
    one_line_error(run_pymb("read", "--map", m + ".missing", "acme-meter", "--port",
                            "/dev/null"), "missing")
    one_line_error(run_pymb("map", "probe", "--port", "/dev/null", "3", "coils:0:2"),
                   "TABLE:START:COUNT")
    for unit in ("0", "256"):  # refused before any port is opened or byte sent
        one_line_error(run_pymb("map", "probe", "--tcp", "127.0.0.1:1", unit, "holding:0:2"),
                       "ADDRESS must be the device's unit id, 1..255")
    twin = meter.parent / "twin.toml"
    twin.write_text(METER)
    one_line_error(run_pymb("read", "--map", m, "--map", str(twin), "acme-meter", "--port",
                            "/dev/null"), "also the id of --map")
    clash = meter.parent / "clash.toml"
    clash.write_text(METER.replace('id = "acme-meter"', 'id = "eastron-sdm120"'))
    one_line_error(run_pymb("read", "--map", str(clash), "eastron-sdm120", "--port",
                            "/dev/null"), "a device pymb ships")


def test_scan_through_a_tcp_gateway_names_a_map_device(meter: Path) -> None:
    with SimulatorProcess(["--map", str(meter), "acme-meter:9", "coolpro:40", "--tcp",
                           "127.0.0.1:0"], quiet=True) as sim:
        r = run_pymb("scan", "--tcp", sim.endpoint, "--range", "8-9,40", "--timeout", "0.3",
                     "--map", str(meter))
        assert r.returncode == 0, r.stderr
        rows = [line.split()[:2] for line in r.stdout.splitlines()]
        assert rows == [["9", "acme-meter"], ["40", "coolpro"]], r.stdout


def test_two_maps_on_one_simulated_bus(meter: Path, tmp_path: Path) -> None:
    other = tmp_path / "other.toml"
    other.write_text(METER.replace('id = "acme-meter"', 'id = "acme-other"')
                     .replace("example = 230.5", "example = 115.0"))
    with SimulatorProcess(["--map", str(meter), "--map", str(other), "acme-meter:3",
                           "acme-other:4"], quiet=True) as sim:
        for device, volts in (("acme-meter:3", 230.5), ("acme-other:4", 115.0)):
            r = run_pymb("read", "--map", str(meter), "--map", str(other), device,
                         "--group", "fast", "--port", sim.port, "--json")
            assert r.returncode == 0, r.stderr
            assert json.loads(r.stdout)["values"]["voltage_v"] == volts


def test_simulate_with_maps_and_no_device_serves_the_maps_devices(meter: Path,
                                                                  tmp_path: Path) -> None:
    """``--map`` without DEVICE serves each map's device at its default
    address, and no CoolPro or hub beside them."""
    other = tmp_path / "other.toml"
    other.write_text(METER.replace('id = "acme-meter"', 'id = "acme-other"')
                     .replace("default_address = 3", "default_address = 5")
                     .replace("example = 230.5", "example = 115.0"))
    with SimulatorProcess(["--map", str(meter), "--map", str(other), "--tcp", "127.0.0.1:0"],
                          quiet=True) as sim:
        r = run_pymb("scan", "--tcp", sim.endpoint, "--range", "1-5,40", "--timeout", "0.3",
                     "--map", str(meter), "--map", str(other))
        assert r.returncode == 0, r.stderr
        assert [line.split()[0] for line in r.stdout.splitlines()] == ["3", "5"], r.stdout
        for device, volts in (("acme-meter:3", 230.5), ("acme-other:5", 115.0)):
            r = run_pymb("read", "--map", str(meter), "--map", str(other), device,
                         "--group", "fast", "--tcp", sim.endpoint, "--json")
            assert r.returncode == 0, r.stderr
            assert json.loads(r.stdout)["values"]["voltage_v"] == volts
