"""The decodings each vendor map's document states, register by register:
word order, weights (scale), sentinels, enumerations. The registers are
written here from the document's rules (not produced by pymb's encoder),
and decoded by the shipped map, in C (``maps.Decoder``) and one point at a
time (``Map.decode``)."""

from __future__ import annotations

import math
import struct
from typing import Any

import pytest

from pymb import maps


def f32(v: float) -> list[int]:
    """An IEEE 754 single as two registers, high word first."""
    hi, lo = struct.unpack(">HH", struct.pack(">f", v))
    return [hi, lo]


def lsw_first(v: int, words: int = 2) -> list[int]:
    """A two's complement integer as registers, least significant word first."""
    u = v & ((1 << (16 * words)) - 1)
    return [(u >> (16 * i)) & 0xFFFF for i in range(words)]


def msw_first(v: int, words: int) -> list[int]:
    return list(reversed(lsw_first(v, words)))


def text(s: str, count: int) -> list[int]:
    b = s.encode("ascii").ljust(2 * count, b"\0")
    return [b[i] << 8 | b[i + 1] for i in range(0, 2 * count, 2)]


#: (map id, point, registers as the device sends them, value, state)
EXAMPLES: list[tuple[str, str, list[int], Any, str]] = [
    # Eastron: IEEE 754 floats, high word first; 230.5 V is 4366 8000h
    ("eastron-sdm230", "voltage_v", [0x4366, 0x8000], 230.5, "value"),
    ("eastron-sdm220", "frequency_hz", f32(49.98), 49.98, "value"),
    ("eastron-sdm72d-m", "total_export_active_power_w", f32(1520.0), 1520.0, "value"),
    ("eastron-sdm72d-m", "l3_current_a", [0x7FC0, 0x0000], None, "nan"),
    # Carlo Gavazzi: INT32 least significant word first; weights V x 10, A x 1000, W x 10
    ("carlo-gavazzi-em24", "l1_voltage_v", [0x0901, 0x0000], 230.5, "value"),
    ("carlo-gavazzi-em24", "l2_current_a", lsw_first(71234), 71.234, "value"),
    ("carlo-gavazzi-em24", "total_active_power_w", lsw_first(-9782), -978.2, "value"),
    ("carlo-gavazzi-em24", "import_active_energy_kwh", lsw_first(12345678), 1234567.8, "value"),
    ("carlo-gavazzi-em24", "phase_sequence", [0xFFFF], -1, "value"),  # L1-L3-L2
    ("carlo-gavazzi-em21", "total_power_factor", [0xFC2E], -0.978, "value"),  # leading
    ("carlo-gavazzi-em21", "frequency_hz", [500], 50.0, "value"),
    # ABB B23/B24: big-endian; 0.01 kWh energies in 64 bits; a missing value is all ones
    ("abb-b23", "import_active_energy_kwh", msw_first(123456789, 4), 1234567.89, "value"),
    ("abb-b23", "net_active_energy_kwh", msw_first(-250, 4), -2.5, "value"),
    ("abb-b23", "l1_voltage_v", msw_first(2305, 2), 230.5, "value"),
    ("abb-b23", "total_active_power_w", msw_first(-123456, 2), -1234.56, "value"),
    ("abb-b23", "l2_current_a", [0xFFFF, 0xFFFF], None, "not_available"),
    ("abb-b23", "total_power_factor", [0x7FFF], None, "not_available"),
    ("abb-b23", "frequency_hz", [5002], 50.02, "value"),
    # Schneider Electric: Float32 and Int64 (Wh) big-endian, text two characters a register
    ("schneider-iem3000", "total_active_power_kw", f32(2.5), 2.5, "value"),
    ("schneider-iem3000", "import_active_energy_wh", msw_first(1234567, 4), 1234567, "value"),
    ("schneider-iem3000", "manufacturer", text("Schneider Electric", 20), "Schneider Electric",
     "value"),
    ("schneider-pm5000", "meter_model", text("PM5340", 20), "PM5340", "value"),
    ("schneider-pm5000", "delivered_active_energy_wh", msw_first(2**40, 4), 2**40, "value"),
    # Janitza: floats high word first
    ("janitza-umg96rm", "rotation_field", f32(-1.0), -1.0, "value"),
    ("janitza-umg96rm", "l1_current_a", f32(4.25), 4.25, "value"),
    # CHINT DTSU666: a float to be multiplied by the table's factor: 2305.0 x 0.1 V
    ("chint-dtsu666", "l1_voltage_v", f32(2305.0), 230.5, "value"),
    ("chint-dtsu666", "l1_current_a", f32(4250.0), 4.25, "value"),
    ("chint-dtsu666", "frequency_hz", f32(4998.0), 49.98, "value"),
    ("chint-dtsu666", "import_active_energy_kwh", f32(1234.5), 1234.5, "value"),
]


def close(got: Any, want: Any) -> bool:
    if isinstance(want, float) and isinstance(got, (int, float)):
        return math.isclose(got, want, rel_tol=1e-7)
    return bool(got == want) and type(got) is type(want)


@pytest.mark.parametrize(("map_id", "point", "regs", "value", "state"), EXAMPLES,
                         ids=[f"{e[0]}:{e[1]}" for e in EXAMPLES])
def test_a_documented_decoding(map_id: str, point: str, regs: list[int], value: Any,
                               state: str) -> None:
    m = maps.builtin(map_id)
    p = m.points[point]
    assert p.count == len(regs)
    assert close(m.decode(point, regs), value), (m.decode(point, regs), value)
    d = maps.Decoder(m, [point])
    got = d.read(regs)
    assert close(got[point], value)
    assert d.states()[point] == state


def test_every_vendor_map_has_documented_decodings() -> None:
    from pymb.devices.mapspec import FACADES

    shipped = [i for i in maps.builtin_ids() if i not in FACADES]
    have = {e[0] for e in EXAMPLES}
    older = {"eastron-sdm120", "eastron-sdm630", "generic-vfd"}  # test_builtin_maps, tests/sim
    assert set(shipped) - older <= have, sorted(set(shipped) - older - have)
