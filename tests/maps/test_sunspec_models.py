"""Every SunSpec model as a pymb map: the models pymb ships are the SunSpec
Alliance's files unchanged (as pysunspec2 ships them), each converts and
loads, and each point sits where pysunspec2 (the Alliance's own library)
puts it, with its type, scale factor and not-implemented value."""

from __future__ import annotations

import random
from importlib import resources
from pathlib import Path

import pytest
import sunspec2
import sunspec2.device as ss_device
from sunspec_peer import model_registers, random_values

from pymb import maps
from pymb.maps import sunspec
from pymb.maps.codec import decode_one
from pymb.maps.sunspec.layout import Placed, left_out, map_text

MODELS = Path(sunspec2.__file__).parent / "models" / "json"
OURS = resources.files("pymb.maps.sunspec")


def test_the_models_are_the_sunspec_files_unchanged() -> None:
    theirs = sorted(p.name for p in MODELS.glob("model_*.json"))
    ours = sorted(f.name for f in (OURS / "models").iterdir() if f.name.endswith(".json"))
    assert ours == theirs
    assert len(ours) >= 100
    for name in theirs:
        assert (OURS / "models" / name).read_bytes() == (MODELS / name).read_bytes(), name
    notice = (OURS / "NOTICE").read_text(encoding="utf-8")
    assert "Apache License, Version 2.0" in notice
    assert "SunSpec Alliance" in notice
    assert "Apache License" in (OURS / "models" / "LICENSE-2.0.txt").read_text(encoding="utf-8")
    assert sunspec.model_ids() == tuple(sorted(int(n[6:-5]) for n in theirs))


@pytest.mark.parametrize("repeats", [1, 3])
def test_every_model_converts_and_loads(repeats: int) -> None:
    for mid in sunspec.model_ids():
        m = sunspec.model_map(mid, repeats=repeats)
        prefix = str(sunspec.model_def(mid)["group"]["name"]) + "."
        assert m.id == f"sunspec-{mid}"
        assert all(n.startswith(prefix) for n in m.points), mid
        assert m.points[prefix + "ID"].address == 40002
        assert m.plan("fast") is not None


def _addresses(m: maps.Map) -> dict[int, tuple[str, int]]:
    """On-wire address -> (point name, channel) of every value of a map."""
    out: dict[int, tuple[str, int]] = {}
    for p in m.points.values():
        for c in range(1, p.channels + 1):
            out[p.address_of(c)] = (p.name, c)
    return out


def _theirs(mid: int, registers: list[int]) -> dict[int, tuple[str, object, int]]:
    """Address -> (SunSpec type, raw value, registers) of each point pysunspec2
    lays out."""
    data = b"".join(r.to_bytes(2, "big") for r in registers)
    model = ss_device.Model(model_id=mid, model_addr=40002, model_len=len(registers) - 2,
                            data=data)
    out: dict[int, tuple[str, object, int]] = {}

    def walk(g: object) -> None:
        for p in g.points.values():  # type: ignore[attr-defined]
            out[40002 + p.offset] = (p.pdef["type"], p.value, p.len)
        for sub in g.groups.values():  # type: ignore[attr-defined]
            for inst in (sub if isinstance(sub, list) else [sub]):
                walk(inst)

    walk(model)
    return out


_WIDTH = {"u16": 1, "i16": 1, "sunssf": 1, "u32": 2, "i32": 2, "f32": 2, "u64": 4, "i64": 4,
          "f64": 4}


def test_every_point_is_where_pysunspec2_puts_it() -> None:
    """Each model with two instances of each repeating group (counting
    points such as NPt set to 2): pymb's map has a value at each point's
    address pysunspec2 computes, none elsewhere, of the type's width; the
    unscaled values agree."""
    rnd = random.Random(35)
    checked = 0
    for mid in sunspec.model_ids():
        regs = model_registers(mid, random_values(mid, rnd, repeats=2))
        theirs = _theirs(mid, regs)
        name = str(sunspec.model_def(mid)["group"]["name"])
        text = map_text([Placed(mid, 40002, len(regs) - 2, name, tuple(regs))], base=40000)
        m = maps.loads(text, source=f"model {mid}")
        ours = _addresses(m)
        expected = {a for a, (t, _, _) in theirs.items() if t != "pad"}
        # a string longer than a request is in parts of 125 registers
        expected |= {a + k for a, (t, _, n) in theirs.items() if t == "string"
                     for k in range(125, n, 125)}
        assert set(ours) == expected, (mid, sorted(set(ours) ^ expected)[:5])
        for address, (typ, value, size) in theirs.items():
            if typ == "pad":
                continue
            point, _ = ours[address]
            p = m.points[point]
            at = address - 40002
            if p.type in _WIDTH:
                assert p.count == _WIDTH[p.type], (mid, point)
            if size > 125:
                assert p.count == 125, (mid, point)
            elif p.scale_from is None and p.scale is None and typ not in ("eui48", "ipv6addr"):
                got = decode_one(p, regs[at:at + p.count])[0]  # the one channel
                if isinstance(value, float):
                    assert got == pytest.approx(value, rel=1e-7), (mid, point)
                else:
                    assert got == value, (mid, point, got, value)
            checked += 1
    assert checked > 4000


def test_types_and_scale_factors_as_sunspec_defines_them() -> None:
    m = sunspec.model_map(103)
    p = m.points
    assert p["inverter_three_phase.W"].type == "i16"
    assert p["inverter_three_phase.W"].scale_from == "inverter_three_phase.W_SF"
    assert p["inverter_three_phase.W_SF"].type == "sunssf"
    assert p["inverter_three_phase.WH"].type == "u32"
    assert p["inverter_three_phase.WH"].kind == "counter"
    assert p["inverter_three_phase.WH"].markers == {0: "not_implemented"}
    assert p["inverter_three_phase.PhVphA"].markers == {0xFFFF: "not_implemented"}
    assert p["inverter_three_phase.St"].values[4] == "MPPT"
    assert p["inverter_three_phase.Evt1"].flags[0] == "GROUND_FAULT"
    for name in ("W", "W_SF", "PhVphA", "A", "Hz", "WH", "St"):
        assert f"inverter_three_phase.{name}" in p
    assert m.decode("inverter_three_phase.PhVphA", [0xFFFF]) is None
    assert m.decode_state("inverter_three_phase.A", [0xFFFF])[1] == "not_implemented"
    mppt = sunspec.model_map(160, repeats=2).points
    dca = mppt["mppt.module.DCA"]
    assert (dca.block, dca.channels, dca.stride) == (True, 2, 20)
    assert dca.scale_from == "mppt.DCA_SF"
    assert mppt["mppt.module[2].IDStr"].type == "string"  # text: a point per module
    meter = sunspec.model_map(213).points
    assert meter["ac_meter_abcn_float.W"].type == "f32"
    curves = sunspec.model_map(705).points
    assert curves["DERVoltVar.Crv.ActPt"].block
    assert curves["DERVoltVar.Crv[1].Pt.V"].scale_from == "DERVoltVar.V_SF"
    # a repeating group with scale factors of its own: a point per instance
    schedule = sunspec.model_map(133, repeats=2).points
    assert schedule["schedule.repeating[2].X1"].scale_from == "schedule.repeating[2].X_SF"
    assert not schedule["schedule.repeating[2].X1"].block


def test_a_model_pymb_does_not_know_is_a_clear_error() -> None:
    with pytest.raises(maps.MapError, match="no SunSpec model 4242"):
        sunspec.model_map(4242)


def test_groups_parts_and_a_second_model_of_a_name() -> None:
    common = sunspec.model_map(1).points
    assert {common[f"common.{n}"].group for n in ("ID", "L", "Mn", "SN")} == {"config"}
    assert common["common.DA"].group == "fast"
    inverter = sunspec.model_map(103).points
    assert inverter["inverter_three_phase.W"].group == "fast"
    assert inverter["inverter_three_phase.W_SF"].group == "fast"
    sim = sunspec.model_map(64411).points  # harmonics as 150-register text: two parts
    first, second = sim["ACSimInterface.VHarA"], sim["ACSimInterface.VHarA_2"]
    assert (first.count, second.count, second.address) == (125, 25, first.address + 125)
    regs = [0x5375, 0x6E53]
    for mid in (1, 213, 213):
        regs += model_registers(mid, {"W": 10.5} if mid == 213 else {})
    regs += [0xFFFF, 0]
    found = sunspec.discover(lambda a, n: regs[a - 40000:a - 40000 + n])
    assert [p.prefix for p in found.models] == ["common", "ac_meter_abcn_float",
                                                 "ac_meter_abcn_float_2"]
    assert found.map_id == "sunspec-1-213-213"
    m = found.map(1)
    assert m.points["ac_meter_abcn_float_2.W"].address == \
        m.points["ac_meter_abcn_float.W"].address + 126


def test_a_count_larger_than_the_model_holds_is_cut_to_its_length() -> None:
    """Model 705 whose NCrv says 60,000 curves but whose L holds two: two."""
    values = {"NPt": 2, "NCrv": 2, "V_SF": -1,
              "Crv": [{"Pt": [{"V": 1}, {"V": 2}]}, {"Pt": [{"V": 3}, {"V": 4}]}]}
    regs = model_registers(705, values)
    ncrv = 6  # offset of NCrv in model 705
    regs[ncrv] = 60000
    placed = Placed(705, 40002, len(regs) - 2, "DERVoltVar", tuple(regs))
    assert left_out(placed) == []  # laid out as two curves, not cut from 60,000
    m = maps.loads(map_text([placed], base=40000), source="model 705")
    assert m.points["DERVoltVar.Crv.ActPt"].channels == 2
    assert "DERVoltVar.Crv[3].Pt.V" not in m.points
