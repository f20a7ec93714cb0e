"""Fleet with a map device: the store-and-forward guarantees of the broker
restart and SIGKILL tests hold for a device read through a map file
(``pymb simulate --map`` + ``pymb log --map``, real mosquitto); the plain
profile carries point names with units in a retained metadata topic;
Sparkplug B births carry each point with its type's datatype, its unit and
its kind (decoded with pysparkplug); influx lines carry the point names."""

from __future__ import annotations

import json
import signal
from pathlib import Path
from typing import Any

import pytest

pytest.register_assert_rewrite("mqtt_broker")
from conftest import run_pymb, wait_until  # noqa: E402
from mqtt_broker import (  # noqa: E402
    Fleet,
    db_ids,
    duplicates,
    plain_ids,
    restart_broker_mid_run,
    stop_log,
)

from pymb.sim import SimulatorProcess  # noqa: E402

pytest_plugins = ["mqtt_broker"]
NODE = "gw-maps"
GROUP = "plant"

#: every type the Sparkplug datatypes name; no groups: read at the bus's interval
METER = '''schema = "pymb.map/1"
[device]
id = "test-meter"
table = "holding"
[[point]]
name = "status_word"
address = 0
type = "u16"
example = 7
[[point]]
name = "temperature_c"
address = 1
type = "i16"
scale = 0.1
unit = "°C"
example = -12.5
[[point]]
name = "offset_i32"
address = 2
type = "i32"
example = -70000
[[point]]
name = "runtime_s"
address = 4
type = "u64"
kind = "counter"
unit = "s"
example = 9007199254740993
[[point]]
name = "voltage_v"
address = 8
type = "f32"
unit = "V"
example = 230.5
[[point]]
name = "energy_kwh"
address = 10
type = "f64"
unit = "kWh"
kind = "counter"
example = 1234.5
[[point]]
name = "model"
address = 14
type = "string"
count = 4
example = "MTR1"
[[point]]
name = "running"
address = 18
type = "bit"
bit = 0
example = true
[[point]]
name = "count_u32"
address = 19
type = "u32"
example = 123456
'''

#: Sparkplug B datatypes (sparkplug_b.proto)
UINT16, INT32, UINT64, FLOAT, DOUBLE, BOOLEAN, STRING, UINT32 = 6, 3, 8, 9, 10, 11, 12, 7


@pytest.fixture
def meter(tmp_path: Path) -> Path:
    path = tmp_path / "meter.toml"
    path.write_text(METER)
    return path


def _sim(fleet: Fleet, meter: Path) -> str:
    return fleet.simulator("--map", str(meter), "test-meter:3").endpoint


def _plain(fleet: Fleet, broker: Any, meter: Path) -> list[str]:
    return ["--map", str(meter), "--mqtt", broker.url, "--mqtt-node", NODE]


def _nothing_lost(what: str, got: list[int], db: Path, killed: int = 0) -> None:
    """Every sample of the database arrived, and no other but those a kill
    took back (published from the batch it lost: ids up to ``killed``)."""
    want = db_ids(db)
    print(f"\n{what}: {len(want)} samples in the database, {len(set(got))} distinct "
          f"received, {duplicates(got)} duplicates")
    assert set(got) >= want
    assert all(i <= killed for i in set(got) - want), sorted(set(got) - want)[:5]


def test_a_map_device_through_a_broker_restart_loses_nothing(fleet: Fleet, meter: Path,
                                                             tmp_path: Path) -> None:
    endpoint = _sim(fleet, meter)
    broker = fleet.broker()
    sub = fleet.subscribe(broker, f"pymb/{NODE}/#")
    db = tmp_path / "log.sqlite"
    proc = fleet.log(endpoint, db, *_plain(fleet, broker, meter), device="test-meter:3")
    restart_broker_mid_run(broker, sub, db)
    err = stop_log(proc)
    assert "nothing left to send" in err
    wait_until(lambda: set(plain_ids(sub.snapshot())) >= db_ids(db), "every sample", 30)
    _nothing_lost("map device, broker restart", plain_ids(sub.snapshot()), db)
    msgs = sub.snapshot()
    data = [json.loads(p) for t, p in msgs if t == f"pymb/{NODE}/test-meter-3"]
    assert data[0]["type"] == "test-meter"
    assert data[0]["values"]["voltage_v"] == 230.5
    assert data[0]["values"]["runtime_s"] == 9007199254740993  # exact past 2**53
    assert data[0]["values"]["model"] == "MTR1"
    assert data[0]["states"]["temperature_c"] == "value"
    meta = [json.loads(p) for t, p in msgs if t == f"pymb/{NODE}/test-meter-3/meta"]
    assert meta, "the retained metadata"
    points = meta[-1]["points"]
    assert meta[-1]["map"] == "test-meter"
    assert points["voltage_v"]["unit"] == "V"
    assert points["energy_kwh"]["kind"] == "counter"
    assert points["temperature_c"]["unit"] == "°C"


def test_a_map_device_through_a_sigkill_loses_nothing(fleet: Fleet, meter: Path,
                                                      tmp_path: Path) -> None:
    endpoint = _sim(fleet, meter)
    broker = fleet.broker()
    sub = fleet.subscribe(broker, f"pymb/{NODE}/#")
    db = tmp_path / "log.sqlite"
    proc = fleet.log(endpoint, db, *_plain(fleet, broker, meter), device="test-meter:3")
    wait_until(lambda: len(plain_ids(sub.snapshot())) >= 200, "200 samples live", 30)
    proc.send_signal(signal.SIGKILL)
    proc.wait(10)
    wait_until(lambda: (f"pymb/{NODE}/status", b"offline") in sub.snapshot(),
               "the last will (offline)", 30)
    killed = max(plain_ids(sub.snapshot()))  # published, maybe taken back by the kill
    proc = fleet.log(endpoint, db, *_plain(fleet, broker, meter), device="test-meter:3")
    wait_until(lambda: sum(1 for i in set(plain_ids(sub.snapshot())) if i > killed) >= 50,
               "samples of the second run", 30)
    stop_log(proc)
    wait_until(lambda: set(plain_ids(sub.snapshot())) >= db_ids(db), "every sample", 30)
    _nothing_lost("map device, SIGKILLed and restarted", plain_ids(sub.snapshot()), db,
                  killed=killed)


def test_sparkplug_births_of_a_map_device(fleet: Fleet, meter: Path, sparkplug_pb: Any,
                                          tmp_path: Path) -> None:
    endpoint = _sim(fleet, meter)
    broker = fleet.broker()
    sub = fleet.subscribe(broker, f"spBv1.0/{GROUP}/+/{NODE}/#")
    db = tmp_path / "log.sqlite"
    proc = fleet.log(endpoint, db, "--map", str(meter), "--mqtt", broker.url,
                     "--mqtt-profile", "sparkplug", "--mqtt-group", GROUP, "--mqtt-node", NODE,
                     device="test-meter:3")
    wait_until(lambda: len(sub.snapshot()) > 20, "20 Sparkplug messages", 30)
    stop_log(proc)
    msgs = [(t.split("/")[2], sparkplug_pb.FromString(p)) for t, p in sub.snapshot()]
    births = [p for k, p in msgs if k == "DBIRTH"]
    assert births
    birth = {m.name: m for m in births[0].metrics}
    want = {"status_word": UINT16, "temperature_c": DOUBLE, "offset_i32": INT32,
            "runtime_s": UINT64, "voltage_v": FLOAT, "energy_kwh": DOUBLE, "model": STRING,
            "running": BOOLEAN, "count_u32": UINT32, "sample": UINT64}
    assert {n: m.datatype for n, m in birth.items()} == want

    def props(m: Any) -> dict[str, Any]:
        return {k: v.string_value for k, v in zip(m.properties.keys, m.properties.values,
                                                 strict=True)}

    assert props(birth["voltage_v"]) == {"engUnit": "V"}
    assert props(birth["energy_kwh"]) == {"engUnit": "kWh", "kind": "counter"}
    assert props(birth["runtime_s"]) == {"engUnit": "s", "kind": "counter"}
    assert props(birth["status_word"]) == {}
    assert birth["voltage_v"].float_value == 230.5
    assert birth["temperature_c"].double_value == -12.5
    assert birth["runtime_s"].long_value == 9007199254740993
    assert birth["model"].string_value == "MTR1"
    assert birth["running"].boolean_value is True
    assert birth["offset_i32"].int_value == (-70000) & 0xFFFFFFFF
    aliases = {m.alias: m for m in births[0].metrics}
    data = [p for k, p in msgs if k == "DDATA"]
    assert data
    for p in data:
        for m in p.metrics:
            assert m.alias in aliases
            assert m.datatype == aliases[m.alias].datatype


def test_influx_lines_carry_point_names(meter: Path) -> None:
    with SimulatorProcess(["--map", str(meter), "test-meter:3", "--tcp", "127.0.0.1:0"],
                          quiet=True) as sim:
        r = run_pymb("log", "--map", str(meter), "--tcp", sim.endpoint, "test-meter:3",
                     "--format", "influx", "--out", "-", "--seconds", "0.3", "--quiet")
    assert r.returncode == 0, r.stderr
    line = next(x for x in r.stdout.splitlines() if x.startswith("pymb_test_meter,"))
    head, fields, _ = line.split(" ")
    assert head == "pymb_test_meter,bus=bus1,device=test-meter-3,address=3,group=-"
    assert fields.split(",") == [
        "status_word=7i", "temperature_c=-12.5", "offset_i32=-70000i",
        "runtime_s=9007199254740993u", "voltage_v=230.5", "energy_kwh=1234.5",
        'model="MTR1"', "running=true", "count_u32=123456i"]
