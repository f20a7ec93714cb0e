"""SunSpec values at their edges, pymb against pysunspec2 (the SunSpec
Alliance's library): every model in one device served by pymodbus over TCP,
each point at an extreme of its type, not implemented, or text that is not
ASCII; and the not-implemented patterns of the SunSpec specification a
device writes in ways pysunspec2 never would (a NaN that is not SunSpec's,
an EUI-48 with its padding set, a string with text after a leading NUL)."""

from __future__ import annotations

import random
import struct
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pytest
import sunspec2.device as ss_device
from sunspec_peer import (
    SKIPPED_TYPES,
    compare,
    image,
    model_registers,
    pysunspec2_values,
    serve,
)

import pymb
from pymb.devices import MapDevice
from pymb.maps import sunspec

#: values at the edges of each SunSpec type (the not-implemented ones are
#: left out of the values: pysunspec2 writes them)
EDGES: dict[str, list[Any]] = {
    "int16": [-32767, 32767, -1, 0], "uint16": [0, 0xFFFE], "count": [0, 0xFFFE],
    "acc16": [1, 0xFFFF], "enum16": [0, 0xFFFE], "bitfield16": [0, 0x7FFF, 0xFFFE, 0x8000],
    "sunssf": [-10, 10, 0, -3, 2], "int32": [-(2**31 - 1), 2**31 - 1, -1],
    "uint32": [0, 2**32 - 2], "acc32": [1, 2**32 - 1], "enum32": [0, 2**32 - 2],
    "bitfield32": [0, 2**32 - 2, 2**31], "ipaddr": [1, 2**32 - 1],
    "int64": [-(2**63 - 1), 2**63 - 1, -1], "uint64": [0, 2**64 - 2, 2**63],
    "acc64": [1, 2**64 - 1],
    "float32": [3.4028234663852886e38, -1.401298464324817e-45, -0.0, 1.5, float("inf")],
    "float64": [1.7976931348623157e308, -5e-324, -0.0, float("-inf")],
    "string": ["ABC  ", "M\u00fcller", " x", "Z" * 250],  # 250: one request of text
}
_COUNTS = {"NPt", "NCrv", "NCrvSet", "NCtl", "NPrt", "NStr", "NMod", "NProf", "IVLen"}


def edge_values(model_id: int, rnd: random.Random) -> dict[str, Any]:
    """Values for ``model_id`` from :data:`EDGES`, two instances of each
    repeating group, a sixth of the points not implemented."""
    def fill(g: Mapping[str, Any]) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for p in g.get("points", []):
            name, typ = p["name"], p["type"]
            if name in ("ID", "L") or typ in SKIPPED_TYPES:
                continue
            if name in _COUNTS:
                out[name] = 2
            elif rnd.random() > 1 / 6:
                v = rnd.choice(EDGES[typ])
                if typ == "string":  # as much as the point holds, whole characters
                    v = v.encode()[:2 * int(p["size"])].decode("utf-8", "ignore")
                out[name] = v
        for s in g.get("groups", []):
            c = s.get("count")
            if c is None:
                out[s["name"]] = fill(s)
            else:
                out[s["name"]] = [fill(s) for _ in range(c if isinstance(c, int) and c else 2)]
        return out

    return fill(ss_device.get_model_def(model_id)["group"])


def test_every_model_at_the_edges_of_its_types_reads_as_pysunspec2_reads_it(
        tmp_path: Path) -> None:
    """Text with trailing spaces and in UTF-8, strings all NUL (not
    implemented: no value, as pysunspec2 and the specification say), the
    extremes of every type, infinities, scale factors -10..10 shared by
    several points before and after them: pymb's value is pysunspec2's."""
    rnd = random.Random(4711)
    registers = image([(mid, edge_values(mid, rnd)) for mid in sunspec.model_ids()])
    with serve(registers, tmp_path) as server:
        dev = server.pysunspec2()
        try:
            theirs = pysunspec2_values(dev)
        finally:
            dev.close()
        with pymb.TcpClient("127.0.0.1", server.port) as c:
            found = sunspec.discover(lambda a, n: c.read_holding_registers(a, n, slave=1))
            m = found.map(1)
            values = MapDevice(c, m, 1).read()
    scale_factors = {a: raw for a, (typ, raw, _) in theirs.items() if typ == "sunssf"}
    assert compare(m, values, theirs, scale_factors) > 4500
    texts = {v for _, (typ, _, v) in theirs.items() if typ == "string"}
    assert {None, "ABC  ", "M\u00fcller", " x"} <= texts


def _theirs(model_id: int, regs: list[int]) -> dict[str, Any]:
    """pysunspec2's values of one model fed its registers, by point name."""
    data = b"".join(r.to_bytes(2, "big") for r in regs)
    model = ss_device.Model(model_id=model_id, model_addr=40002, model_len=len(regs) - 2,
                            data=data)
    return {name: p.value for name, p in model.points.items()}


def _read(regs: list[int], tmp: Path) -> tuple[dict[str, Any], dict[str, Any]]:
    with serve([0x5375, 0x6E53, *regs, 0xFFFF, 0], tmp) as server, \
            pymb.TcpClient("127.0.0.1", server.port) as c:
        m = sunspec.discover(lambda a, n: c.read_holding_registers(a, n, slave=1)).map(1)
        dev = MapDevice(c, m, 1)
        return dev.read(), dict(dev.states)


def test_not_implemented_patterns_a_device_writes_its_own_way(tmp_path: Path) -> None:
    """Model 11 (its MAC an eui48, its name a string) and model 111 (float32
    points): SunSpec's NaN and all-NUL text are not implemented; another
    NaN reads no value either (state nan); an EUI-48 is its 6 bytes, the
    padding whatever it holds, all-ones (and all-zero) not implemented."""
    mac = [(0xFFFF, 0x0011, 0x2233, 0x4455), (0xFFFF,) * 4, (0, 0, 0, 0),
           (0x0000, 0xFFFF, 0xFFFF, 0xFFFF)]
    names = [[0] * 4, [0, 0x4142, 0, 0], [0x4142, 0x4320, 0x2000, 0], [0x4D, 0, 0, 0]]
    for m11, text in zip(mac, names, strict=True):
        regs = model_registers(11, {"Spd": 100})
        regs[5:9], regs[9:13] = m11, text
        theirs = _theirs(11, regs)
        values, states = _read(regs, tmp_path)
        ours = values["model_11.MAC"]
        assert (None if ours is None else
                ":".join(f"{b:02X}" for b in ours.to_bytes(6, "big"))) == theirs["MAC"]
        assert values["model_11.Nam"] == theirs["Nam"], text
        if theirs["Nam"] is None:
            assert states["model_11.Nam"] == "not_implemented"
    f32 = model_registers(111, {"A": 1.5, "W": 100.0})
    f32[2:4] = struct.unpack(">2H", struct.pack(">I", 0x7FC00000))  # A: SunSpec's NaN
    f32[4:6] = struct.unpack(">2H", struct.pack(">I", 0xFFC00001))  # AphA: another NaN
    values, states = _read(f32, tmp_path)
    theirs = _theirs(111, f32)
    assert (theirs["A"], theirs["AphA"], theirs["W"]) == (None, None, 100.0)
    prefix = "inverter_single_phase_float."
    assert values[prefix + "A"] is None
    assert states[prefix + "A"] == "not_implemented"
    assert values[prefix + "AphA"] is None
    assert states[prefix + "AphA"] == "nan"
    assert values[prefix + "W"] == 100.0


def test_a_scale_factor_outside_sunspecs_range_gives_no_value(tmp_path: Path) -> None:
    """SunSpec's scale factors are -10..10: at the edges the value is
    pysunspec2's; past them (a device writing 11 or -11) no value, state
    ``no_scale``, where pysunspec2 would scale by 10^11 regardless."""
    for sf, expected in ((10, True), (-10, True), (11, False), (-11, False)):
        regs = model_registers(103, {"W": 3342, "W_SF": sf, "A": 7, "A_SF": sf})
        values, states = _read(regs, tmp_path)
        theirs = _theirs(103, regs)
        for name in ("W", "A"):
            ours = values[f"inverter_three_phase.{name}"]
            if expected:
                assert ours == pytest.approx(theirs[name] * 10.0 ** sf, rel=1e-12), (sf, name)
            else:
                assert ours is None, (sf, name)
                assert states[f"inverter_three_phase.{name}"] == "no_scale"
