"""SunSpec discovery and reading against a device that is not pymb: pysunspec2
(the SunSpec Alliance's library) builds the register image, pymodbus serves
it over TCP on 127.0.0.1 in its own process, and pysunspec2's own Modbus
client reads it back; pymb's values must be pysunspec2's, value by value."""

from __future__ import annotations

import json
import random
from pathlib import Path
from typing import Any

import pytest
from conftest import run_pymb
from sunspec_peer import compare, image, pysunspec2_values, random_values, serve

import pymb
from pymb import maps
from pymb.devices import MapDevice
from pymb.devices.mapreading import MapReading
from pymb.maps import sunspec
from pymb.store import samples_after

INVERTER: list[tuple[int, dict[str, Any]]] = [
    (1, {"Mn": "Acme Solar", "Md": "AS-10K", "SN": "SN0042", "Vr": "1.2.3"}),
    (103, {"A": 1234, "A_SF": -2, "AphA": 411, "PhVphA": 2301, "PhVphB": 2299, "V_SF": -1,
           "W": 3342, "W_SF": 0, "Hz": 5001, "Hz_SF": -2, "WH": 123456, "WH_SF": 0,
           "St": 4, "Evt1": 0b101}),  # PhVphC, VA, ... not implemented
    (120, {"DERTyp": 4, "WRtg": 10000, "WRtg_SF": 0, "VARtg": 1000, "VARtg_SF": 1}),
    (160, {"DCA_SF": -2, "DCV_SF": -1, "DCW_SF": 0, "N": 3,
           "module": [{"ID": 1, "IDStr": "east", "DCA": 812, "DCV": 4012, "DCW": 3258},
                      {"ID": 2, "IDStr": "west", "DCA": 15, "DCV": 3990},
                      {"ID": 3, "DCA": 0}]}),
    (213, {"A": 12.5, "PhVphA": 230.25, "W": -1500.5, "Hz": 50.0, "TotWhImp": 12345.0}),
    (705, {"Ena": 1, "NPt": 3, "NCrv": 2, "V_SF": -1, "DeptRef_SF": 0, "RspTms_SF": 0,
           "Crv": [{"ActPt": 3, "Pt": [{"V": 900, "Var": 30}, {"V": 1000, "Var": 0},
                                       {"V": 1100, "Var": -30}]},
                   {"ActPt": 2, "Pt": [{"V": 950}, {"V": 1050}, {}]}]}),
]
UNKNOWN = [64999, 4, 1, 2, 3, 4]  # a vendor model pymb does not know


def test_every_model_in_one_device_reads_as_pysunspec2_reads_it(tmp_path: Path) -> None:
    """A device of all 112 models, two instances of each repeating group,
    random values (a tenth not implemented): every point pymb reads is the
    value pysunspec2 computes (scale factors applied) or, where the scale
    factor is not implemented, no value."""
    rnd = random.Random(3502)
    registers = image([(mid, random_values(mid, rnd)) for mid in sunspec.model_ids()])
    with serve(registers, tmp_path) as server:
        dev = server.pysunspec2()
        try:
            theirs = pysunspec2_values(dev)
        finally:
            dev.close()
        with pymb.TcpClient("127.0.0.1", server.port) as c:
            found = sunspec.discover(lambda a, n: c.read_holding_registers(a, n, slave=1))
            assert [p.id for p in found.models] == list(sunspec.model_ids())
            assert found.base == 40000
            assert not found.skipped
            m = found.map(1)
            values = MapDevice(c, m, 1).read()
    scale_factors = {a: raw for a, (typ, raw, _) in theirs.items() if typ == "sunssf"}
    assert compare(m, values, theirs, scale_factors) > 4500


def _serve_inverter(tmp: Path, base: int = 40000, unit: int = 1) -> Any:
    regs = image(INVERTER)
    regs = regs[:-2] + UNKNOWN + regs[-2:]
    return serve(regs, tmp, base=base, unit=unit)


def test_read_sunspec_device_from_the_command_line(tmp_path: Path) -> None:
    with _serve_inverter(tmp_path) as server:
        r = run_pymb("read", "sunspec:1", "--tcp", f"127.0.0.1:{server.port}", "--json")
        assert r.returncode == 0, r.stderr
        dev = server.pysunspec2()
        try:
            theirs = pysunspec2_values(dev)
        finally:
            dev.close()
    out = json.loads(r.stdout)
    assert r.stderr == ("pymb: sunspec:1: model 64999 at 40393 (L = 4) skipped: pymb does not "
                        "know it\n")
    assert out["device"] == "sunspec-1-103-120-160-213-705"
    values, states = out["values"], out["states"]
    assert values["inverter_three_phase.W"] == 3342
    assert values["inverter_three_phase.A"] == pytest.approx(12.34)
    assert values["inverter_three_phase.PhVphA"] == pytest.approx(230.1)
    assert values["inverter_three_phase.PhVphC"] is None
    assert states["inverter_three_phase.PhVphC"] == "not_implemented"
    assert values["inverter_three_phase.St"] == 4
    assert values["common.Mn"] == "Acme Solar"
    assert values["mppt.module.DCA"] == pytest.approx([8.12, 0.15, 0.0])
    assert values["mppt.module.DCW"] == [3258, None, None]
    assert values["mppt.module[2].IDStr"] == "west"
    assert values["ac_meter_abcn_float.W"] == -1500.5
    assert values["DERVoltVar.Crv[1].Pt.V"] == pytest.approx([90.0, 100.0, 110.0])
    assert values["DERVoltVar.Crv[2].Pt.V"] == pytest.approx([95.0, 105.0, None])
    sfs = {a: raw for a, (typ, raw, _) in theirs.items() if typ == "sunssf"}
    assert compare(_inverter_map(), values, theirs, sfs) > 200


def _inverter_map() -> maps.Map:
    """The map pymb makes of the inverter, from its registers."""
    regs = image(INVERTER)
    regs = regs[:-2] + UNKNOWN + regs[-2:]
    return sunspec.discover(lambda a, n: regs[a - 40000:a - 40000 + n]).map(1)


@pytest.mark.parametrize("base", [0, 50000])
def test_probe_finds_suns_at_each_base_and_saves_the_map(tmp_path: Path, base: int) -> None:
    saved = tmp_path / "inverter.toml"
    with _serve_inverter(tmp_path, base=base, unit=3) as server:
        tcp = f"127.0.0.1:{server.port}"
        r = run_pymb("map", "probe", "3", "--sunspec", "--tcp", tcp, "--save", str(saved))
        assert r.returncode == 0, r.stderr
        assert f"'SunS' at holding {base}; Acme Solar AS-10K" in r.stdout
        assert "model 103   at" in r.stdout
        assert "inverter_three_phase" in r.stdout
        assert "model 64999 at" in r.stdout
        assert "skipped, pymb does not know this model" in r.stdout
        assert saved.is_file()
        again = run_pymb("map", "probe", "3", "--sunspec", "--tcp", tcp, "--save", str(saved))
        assert again.returncode == 2
        assert "exists" in again.stderr
        assert again.stderr.count("\n") == 1  # one line, no traceback
        js = run_pymb("map", "probe", "3", "--sunspec", "--tcp", tcp, "--json")
        assert js.returncode == 0, js.stderr
        info = json.loads(js.stdout)
        assert info["base"] == base
        assert [x["id"] for x in info["models"]] == [1, 103, 120, 160, 213, 705, 64999]
        assert info["models"][-1]["skipped"]
        # the saved map is a map file like any other: --map, and map = "FILE" in a TOML
        r = run_pymb("read", "--map", str(saved), "sunspec-1-103-120-160-213-705:3",
                     "--tcp", tcp, "--json")
        assert r.returncode == 0, r.stderr
        assert json.loads(r.stdout)["values"]["inverter_three_phase.W"] == 3342
        (tmp_path / "log.toml").write_text(
            f'[output]\npath = "{tmp_path / "solar.sqlite"}"\n[[bus]]\ntcp = "{tcp}"\n'
            '[[bus.device]]\nmap = "inverter.toml"\naddress = 3\n')
        r = run_pymb("log", "--config", str(tmp_path / "log.toml"), "--seconds", "1", "--quiet")
        assert r.returncode == 0, r.stderr
    logged = [s.data.values for s in samples_after(tmp_path / "solar.sqlite", 0, limit=100)
              if isinstance(s.data, MapReading)]
    assert any(v.get("inverter_three_phase.W") == 3342 for v in logged)


def test_no_sunspec_device_is_one_line_and_exit_3(tmp_path: Path) -> None:
    with serve([1, 2, 3, 4], tmp_path, base=40000) as server:
        r = run_pymb("map", "probe", "1", "--sunspec", "--tcp", f"127.0.0.1:{server.port}")
    assert r.returncode == 3
    assert "no SunSpec device: 'SunS'" in r.stderr
    assert "40000: 0001 0002" in r.stderr
    assert r.stderr.count("\n") == 1


def test_a_model_shorter_than_sunspec_defines_leaves_its_last_points_out(tmp_path: Path) -> None:
    """An inverter whose model 103 stops after 35 of its 50 registers: the
    points past its end (and those whose scale factor is past it) are not
    read from the next model's registers; the others read as they are."""
    full = image(INVERTER[:2])
    at = 2 + 68  # SunS, then model 1 (ID, L, 66 registers)
    assert full[at:at + 2] == [103, 50]
    short = [*full[:at], 103, 35, *full[at + 2:at + 37], 0xFFFF, 0]
    with serve(short, tmp_path) as server:
        tcp = f"127.0.0.1:{server.port}"
        probe = run_pymb("map", "probe", "1", "--sunspec", "--tcp", tcp, "--json")
        read = run_pymb("read", "sunspec:1", "--tcp", tcp, "--json")
    assert probe.returncode == 0, probe.stderr
    (note,) = json.loads(probe.stdout)["notes"]
    assert "model 103 at 40070 (L = 35) is shorter than SunSpec defines it" in note
    assert read.returncode == 0, read.stderr
    values = json.loads(read.stdout)["values"]
    assert values["inverter_three_phase.W"] == 3342
    assert values["inverter_three_phase.DCA_SF"] is None  # offset 28: inside, not implemented
    for name in ("TmpOt", "Tmp_SF", "St", "Evt1",  # offsets 36 and on: past the 37 registers
                 "TmpCab", "TmpSnk"):  # scaled by Tmp_SF
        assert f"inverter_three_phase.{name}" not in values, name


def test_a_sunspec_device_takes_a_name_only(tmp_path: Path) -> None:
    r = run_pymb("read", "sunspec:1,channels=3", "--tcp", "127.0.0.1:9")
    assert r.returncode == 2
    assert "a sunspec device takes only name=..." in r.stderr
    assert r.stderr.count("\n") == 1
    with _serve_inverter(tmp_path) as server:
        w = run_pymb("watch", "sunspec:1,name=roof", "--tcp", f"127.0.0.1:{server.port}",
                     "--count", "2", "--json")
    assert w.returncode == 0, w.stderr
    readings = [json.loads(line) for line in w.stdout.splitlines()]
    assert len(readings) == 2
    assert all(x["values"]["inverter_three_phase.W"] == 3342 for x in readings)
