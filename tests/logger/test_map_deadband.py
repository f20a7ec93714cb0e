"""``--deadband NAME=AMOUNT`` for a map device's point, end to end: ``pymb
log --on-change`` polling a scripted Modbus TCP responder (not pymb's
simulator) whose voltage wobbles by less than the deadband and then jumps;
what the SQLite file holds is read back. And where a deadband given for the
whole run goes: a built-in quantity to the on-change rules, a point name to
the map devices that have it (the command line over a device's TOML table,
``[output]`` under it), anything else a one-line error with a did-you-mean."""

from __future__ import annotations

import itertools
import struct
from collections.abc import Sequence
from pathlib import Path

import pytest
from conftest import run_pymb
from peerkit import Reply
from peers import TcpPeer

from pymb.cli import build_parser
from pymb.commands.logconfig import config_from
from pymb.devices.deviceconfig import DeviceConfig
from pymb.devices.mapreading import MapReading
from pymb.errors import InvalidArgument
from pymb.logger import load_config
from pymb.logger.config import BusConfig
from pymb.store import samples_after

METER = '''schema = "pymb.map/1"
[device]
id = "band-meter"
table = "input"
[[point]]
name = "voltage_v"
address = 0
type = "f32"
unit = "V"
[[point]]
name = "energy_kwh"
address = 2
type = "u32"
kind = "counter"
'''

JUMP_AT = 30  #: the poll from which the voltage is 2 V higher
WOBBLE = 0.25  #: the voltage's step between polls, under the 0.5 V deadband


class WobblingMeter(TcpPeer):
    """Poll i reads 230 V (232 V from poll JUMP_AT) plus WOBBLE on odd polls,
    and a constant energy counter."""

    def __init__(self) -> None:
        super().__init__({1})
        self.polls = 0

    def reply_for(self, slave: int, pdu: bytes) -> Reply:
        if pdu[0] == 4:
            i = self.polls
            self.polls += 1
            volts = (230.0 if i < JUMP_AT else 232.0) + WOBBLE * (i % 2)
            self.memory.inputs[0:4] = [*struct.unpack(">2H", struct.pack(">f", volts)), 0, 1234]
        return super().reply_for(slave, pdu)


def test_a_point_deadband_from_the_command_line_end_to_end(tmp_path: Path) -> None:
    meter = tmp_path / "meter.toml"
    meter.write_text(METER)
    db = tmp_path / "band.sqlite"
    with WobblingMeter() as peer:
        r = run_pymb("log", "--map", str(meter), "--tcp", f"127.0.0.1:{peer.port}",
                     "band-meter:1", "--on-change", "--deadband", "voltage_v=0.5",
                     "--heartbeat", "1", "--interval", "0.02", "--seconds", "2.5",
                     "--out", str(db), "--quiet")
        polls = peer.polls
    assert r.returncode == 0, r.stderr
    assert polls > JUMP_AT + 10, polls
    stored = samples_after(db, 0, limit=1_000)
    got: list[tuple[float, float]] = []
    for s in stored:
        assert isinstance(s.data, MapReading)
        volts = s.data.values["voltage_v"]
        assert isinstance(volts, float)
        got.append((s.monotonic, volts))
    assert len(got) < polls // 3, (len(got), polls)
    assert got[0][1] == 230.0  # the first poll is stored
    assert any(v >= 232.0 for _, v in got), got  # the jump is stored
    heartbeats = 0
    for (t0, v0), (t1, v1) in itertools.pairwise(got):
        if abs(v1 - v0) <= 0.5:  # within the deadband: stored only by the heartbeat
            assert t1 - t0 >= 1.0 - 1e-6, (t0, v0, t1, v1)
            heartbeats += 1
    assert heartbeats >= 1, got


def test_a_deadband_name_that_is_neither_quantity_nor_point(tmp_path: Path) -> None:
    meter = tmp_path / "meter.toml"
    meter.write_text(METER)
    r = run_pymb("log", "--map", str(meter), "--tcp", "127.0.0.1:1", "band-meter:1",
                 "--on-change", "--deadband", "voltage=0.5", "--seconds", "1",
                 "--out", str(tmp_path / "x.sqlite"))
    assert r.returncode == 2, r.stderr
    assert r.stderr.strip() == ("pymb log: no quantity or point 'voltage' for a deadband; "
                                "did you mean 'voltage_v'?"), r.stderr
    # a point of a map that is not logged is not a name of this run
    r = run_pymb("log", "--port", "/dev/null", "hub", "--on-change", "--deadband",
                 "voltage_v=0.5", "--seconds", "1", "--out", str(tmp_path / "y.sqlite"))
    assert r.returncode == 2, r.stderr
    assert "no quantity or point 'voltage_v' for a deadband" in r.stderr
    assert not (tmp_path / "x.sqlite").exists()
    assert not (tmp_path / "y.sqlite").exists()


def _map_devices(buses: Sequence[BusConfig]) -> dict[str, DeviceConfig]:
    return {d.name: d for b in buses for d in b.devices}


def test_where_a_run_wide_deadband_goes(tmp_path: Path) -> None:
    (tmp_path / "meter.toml").write_text(METER)
    cfg = tmp_path / "log.toml"
    cfg.write_text('''maps = ["meter.toml"]
[output]
on_change = true
deadband = { voltage_v = 0.5, temperature_c = 0.2 }
[[bus]]
tcp = "127.0.0.1:1"
[[bus.device]]
type = "band-meter"
address = 1
[[bus.device]]
type = "band-meter"
address = 2
deadband = { voltage_v = 2 }
[[bus.device]]
type = "eastron-sdm120"
address = 3
[[bus.device]]
type = "hub"
address = 4
''')
    c = load_config(cfg)
    assert c.on_change is not None
    assert c.on_change.deadband == {"temperature_c": 0.2}
    devs = _map_devices(c.buses)
    # [output] under the device's own table; to each map device with the point
    assert dict(devs["band-meter-1"].deadband) == {"voltage_v": 0.5}
    assert dict(devs["band-meter-2"].deadband) == {"voltage_v": 2.0}
    assert dict(devs["eastron-sdm120-3"].deadband) == {"voltage_v": 0.5}
    assert dict(devs["hub-4"].deadband) == {"temperature_c": 0.2}
    # the command line over both
    args = build_parser("log").parse_args(
        ["log", "--config", str(cfg), "--on-change", "--deadband", "voltage_v=1",
         "--deadband", "humidity_pct=3"])
    c, _ = config_from(args)
    assert c.on_change is not None
    assert c.on_change.deadband == {"temperature_c": 0.2, "humidity_pct": 3.0}
    assert {n: dict(d.deadband) for n, d in _map_devices(c.buses).items()} == {
        "band-meter-1": {"voltage_v": 1.0}, "band-meter-2": {"voltage_v": 1.0},
        "eastron-sdm120-3": {"voltage_v": 1.0},
        # the hub's points by those names: the same bands as the run's
        "hub-4": {"temperature_c": 0.2, "humidity_pct": 3.0}}
    for bad, says in (("voltage_v=-1", "deadband of voltage_v must be 0 or more"),
                      ("voltage_v=nan", "deadband of voltage_v must be 0 or more"),
                      ("voltage_v", "--deadband takes NAME=AMOUNT")):
        args = build_parser("log").parse_args(
            ["log", "--config", str(cfg), "--on-change", "--deadband", bad])
        with pytest.raises(InvalidArgument, match=says):
            config_from(args)
    cfg.write_text(cfg.read_text().replace("voltage_v = 0.5", "voltge_v = 0.5"))
    with pytest.raises(InvalidArgument, match=f"^{cfg}: output: no quantity or point "
                                              "'voltge_v' for a deadband; did you mean "
                                              "'voltage_v'"):
        load_config(cfg)
