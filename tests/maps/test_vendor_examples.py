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
from regwords import f32, lsw_first

from pymb import maps


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
    # an overflow: the most significant word is 7FFFh, whatever the least significant one
    ("carlo-gavazzi-em24", "l1_current_a", [0x0000, 0x7FFF], None, "overflow"),
    ("carlo-gavazzi-em24", "total_active_power_w", [0xFFFF, 0x7FFF], None, "overflow"),
    ("carlo-gavazzi-em21", "import_active_energy_kwh", [0x1234, 0x7FFF], None, "overflow"),
    ("carlo-gavazzi-em340", "l1_voltage_v", [0x0901, 0x7FFF], None, "overflow"),
    ("carlo-gavazzi-em24", "l1_current_a", [0xFFFF, 0x7FFE], 2147418.111, "value"),  # not one
    ("carlo-gavazzi-em24", "version_code", [0], 0, "value"),  # version A
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
    # Huawei SUN2000: big-endian, divided by the gain
    ("huawei-sun2000", "active_power_kw", msw_first(9300, 2), 9.3, "value"),
    ("huawei-sun2000", "pv1_current_a", [825], 8.25, "value"),
    ("huawei-sun2000", "internal_temperature_c", [0xFFEC], -2.0, "value"),
    ("huawei-sun2000", "device_status", [0x0200], 0x0200, "value"),  # on-grid
    ("huawei-sun2000", "model", text("SUN2000-10KTL-M1", 15), "SUN2000-10KTL-M1", "value"),
    # Growatt: 0.1 W in 32 bits, high word first
    ("growatt-inverter", "pv_power_w", msw_first(34567, 2), 3456.7, "value"),
    ("growatt-inverter", "grid_frequency_hz", [5001], 50.01, "value"),
    ("growatt-inverter", "time_total_s", msw_first(7200, 2), 3600.0, "value"),  # 0.5 s units
    # Sungrow: U32/S32 low word first
    ("sungrow-sg", "total_energy_kwh", [0x1170, 0x0001], 70000, "value"),
    ("sungrow-sg", "reactive_power_var", lsw_first(-120), -120, "value"),
    ("sungrow-sg", "grid_frequency_hz", [500], 50.0, "value"),
    ("sungrow-sg", "work_state", [0x5500], 0x5500, "value"),  # fault
    # SMA: NaN patterns per type; FIX2 = two decimals
    ("sma-inverter", "active_power_w", [0x8000, 0x0000], None, "not_available"),
    ("sma-inverter", "l1_voltage_v", [0xFFFF, 0xFFFF], None, "not_available"),
    ("sma-inverter", "l1_voltage_v", msw_first(23050, 2), 230.5, "value"),
    ("sma-inverter", "condition", [0x00FF, 0xFFFD], None, "not_available"),
    ("sma-inverter", "condition", [0, 307], 307, "value"),  # Ok
    ("sma-inverter", "total_yield_wh", [0xFFFF] * 4, None, "not_available"),
    ("sma-inverter", "total_yield_wh", msw_first(12345678, 4), 12345678, "value"),
    # Victron GX: divided by the list's scale factor
    ("victron-gx-system", "battery_current_a", [0xFF83], -12.5, "value"),
    ("victron-gx-system", "grid_l1_w", [0xFEA2], -350, "value"),
    ("victron-gx-vebus", "input_l1_power_w", [103], 1030.0, "value"),  # scale factor 0.1
    ("victron-gx-vebus", "battery_voltage_v", [5241], 52.41, "value"),
    ("victron-gx-vebus", "state", [9], 9, "value"),  # inverting
    ("victron-gx-grid", "l1_energy_from_net_kwh", [12345], 123.45, "value"),
    ("victron-gx-battery", "temperature_c", [0xFFF6], -1.0, "value"),
    ("victron-gx-battery", "soc_pct", [785], 78.5, "value"),
    # KOSTAL: Float32 low word first (CDAB)
    ("kostal-plenticore", "l1_voltage_v", [0x8000, 0x4366], 230.5, "value"),
    ("kostal-plenticore", "powermeter_total_active_power_w", list(reversed(f32(-2500.0))),
     -2500.0, "value"),
    # Schneider ATV320: ETA 0637h = ready, switched on, operation enabled, voltage, quick stop off
    ("schneider-atv320", "status_word", [0x0637], 0x0637, "value"),
    ("schneider-atv320", "output_frequency_hz", [0xFE0C], -50.0, "value"),  # reverse
    ("schneider-atv320", "frequency_reference_hz", [500], 50.0, "value"),
    ("schneider-atv320", "command_word", [0x000F], 0x000F, "value"),  # enable operation
    # the DRIVECOM state is ETA AND 006Fh, whatever the other bits say
    ("schneider-atv320", "drive_state", [0x0637], 0x0027, "value"),  # operation enabled
    ("schneider-atv320", "drive_state", [0x0250], 0x0040, "value"),  # switch on disabled
    ("schneider-atv320", "drive_state", [0x8231], 0x0021, "value"),  # ready to switch on
    ("schneider-atv320", "drive_state", [0x0217], 0x0007, "value"),  # quick stop active
    ("schneider-atv320", "drive_state", [0x0218], 0x0008, "value"),  # fault
    # ABB ACS580: 20000 = 100 % of the scaling parameter
    ("abb-acs580", "reference1_pct", [20000], 100.0, "value"),
    ("abb-acs580", "actual1_pct", [0xB1E0], -100.0, "value"),
    ("abb-acs580", "control_word", [0x047F], 0x047F, "value"),  # run
    # Siemens V20 and Danfoss FC: 4000h = 100 %
    ("siemens-v20", "setpoint_pct", [0x4000], 100.0, "value"),
    ("siemens-v20", "actual_pct", [0x2000], 50.0, "value"),
    ("danfoss-fc", "reference_pct", [0x4000], 100.0, "value"),
    ("danfoss-fc", "main_actual_value_pct", [0xC000], -100.0, "value"),
    # KEBA: UNSIGNED32 high word first; mA, mW, 0.1 Wh
    ("keba-p30", "l1_current_a", msw_first(16000, 2), 16.0, "value"),
    ("keba-p30", "active_power_w", msw_first(11040500, 2), 11040.5, "value"),
    ("keba-p30", "total_energy_wh", msw_first(38101, 2), 38101, "value"),  # the guide's examples
    ("keba-p30", "active_power_w", msw_first(98661, 2), 98.661, "value"),
    ("keba-p30", "l3_current_a", msw_first(645, 2), 0.645, "value"),
    ("keba-p30", "l1_voltage_v", msw_first(230, 2), 230, "value"),
    ("keba-p30", "serial_number", msw_first(18416854, 2), 18416854, "value"),
    ("keba-p30", "product_type", msw_first(304111, 2), 304111, "value"),
    ("keba-p30", "charging_state", msw_first(3, 2), 3, "value"),  # charging
    # Alfen: FLOAT32/FLOAT64 big-endian, mode 3 state as text
    ("alfen-ng9xx", "total_active_power_w", f32(10980.0), 10980.0, "value"),
    ("alfen-ng9xx", "delivered_energy_wh", list(struct.unpack(">4H", struct.pack(">d", 1234567.5))),
     1234567.5, "value"),
    ("alfen-ng9xx", "mode3_state", text("C2", 5), "C2", "value"),
    # Carlo Gavazzi EM340: as the EM24, least significant word first
    ("carlo-gavazzi-em340", "l3_current_a", lsw_first(5001), 5.001, "value"),
    ("carlo-gavazzi-em340", "total_active_power_w", lsw_first(-12345), -1234.5, "value"),
    # SolaX: 16-bit values, signed battery current and power
    ("solax-x1-hybrid", "battery_current_a", [0xFF83], -12.5, "value"),
    ("solax-x1-hybrid", "grid_frequency_hz", [5001], 50.01, "value"),
    ("solax-x1-hybrid", "run_mode", [2], 2, "value"),  # normal
    # Huawei meter and battery through the inverter
    ("huawei-dtsu666-h", "active_power_w", msw_first(-1500, 2), -1500, "value"),
    ("huawei-dtsu666-h", "l1_voltage_v", msw_first(2305, 2), 230.5, "value"),
    ("huawei-luna2000", "soc_pct", [655], 65.5, "value"),
    ("huawei-luna2000", "total_charge_kwh", msw_first(123456, 2), 1234.56, "value"),
    ("victron-gx-solarcharger", "pv_voltage_v", [9525], 95.25, "value"),
    ("victron-gx-solarcharger", "charge_state", [3], 3, "value"),  # bulk
    # Finder 7E.23: the manual's own example, high register first, 0.01 kWh
    ("finder-7e23", "import_energy_kwh", [13, 60383], 9123.51, "value"),
    ("finder-7e23", "export_energy_kwh", [13, 60383], 9123.51, "value"),
    ("finder-7e23", "firmware_version", [11], 1.1, "value"),  # FW 1.1
    ("finder-7e23", "baud_rate", [1, 49664], 115200, "value"),  # the manual's example
    # NIBE S-series: signed 16-bit temperatures, division factor 10; frequency unsigned, factor 10
    ("nibe-s-series", "outdoor_temperature_c", [0xFFCE], -5.0, "value"),
    ("nibe-s-series", "hot_water_top_c", [495], 49.5, "value"),
    ("nibe-s-series", "compressor_frequency_hz", [525], 52.5, "value"),
    ("nibe-s-series", "heating_offset", [0xFFFE], -2, "value"),  # 8-bit setting, sign-extended
    # NIBE F-series (MODBUS 40): s16 divided by the list's factor 10; prio 30 = heat
    ("nibe-f-series", "outdoor_temperature_c", [0xFFDD], -3.5, "value"),
    ("nibe-f-series", "degree_minutes", [0xFB4B], -120.5, "value"),
    ("nibe-f-series", "compressor_frequency_hz", [485], 48.5, "value"),
    ("nibe-f-series", "priority", [30], 30, "value"),
    # STIEBEL ELTRON ISG: signed 16-bit, 0.1 °C, 0.01 bar; 8000h for a sensor not fitted
    ("stiebel-eltron-isg", "outside_temperature_c", [0xFFE8], -2.4, "value"),
    ("stiebel-eltron-isg", "actual_dhw_temperature_c", [487], 48.7, "value"),
    ("stiebel-eltron-isg", "heating_pressure_bar", [185], 1.85, "value"),
    ("stiebel-eltron-isg", "actual_temperature_hk2_c", [0x8000], None, "not_available"),
    # Socomec COUNTIS: 32 bits high word first; V/100, A/1000, kW/100 signed
    ("socomec-countis-e3x", "l1_voltage_v", msw_first(23050, 2), 230.5, "value"),
    ("socomec-countis-e3x", "l2_current_a", msw_first(12345, 2), 12.345, "value"),
    ("socomec-countis-e3x", "total_active_power_w", msw_first(-152, 2), -1520.0, "value"),
    ("socomec-countis-e3x", "total_power_factor", msw_first(-978, 2), -0.978, "value"),  # leading
    ("socomec-countis-e3x", "product_order_id", [100], 100, "value"),  # Countis
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
    from pymb.devices.mapspec import TYPED_VIEWS

    shipped = [i for i in maps.builtin_ids() if i not in TYPED_VIEWS]
    have = {e[0] for e in EXAMPLES}
    older = {"eastron-sdm120", "eastron-sdm630", "generic-vfd"}  # test_builtin_maps, tests/sim
    assert set(shipped) - older <= have, sorted(set(shipped) - older - have)


#: (map id, writable point, value, registers the document says the device takes)
WRITES: list[tuple[str, str, Any, list[int]]] = [
    ("keba-p30", "set_charging_current_a", 8.0, [8000]),  # "value 8000: 8 A"
    ("keba-p30", "set_energy_wh", 10.0, [1]),  # "value 1: 10 Wh"
    ("keba-p30", "enable_station", "disable", [0]),
    ("schneider-atv320", "command_word", "run_forward", [0x000F]),
    ("schneider-atv320", "frequency_reference_hz", -25.0, [0xFF06]),
    ("abb-acs580", "reference1_pct", 100.0, [20000]),
    ("siemens-v20", "setpoint_pct", 100.0, [0x4000]),
    ("danfoss-fc", "reference_pct", -100.0, [0xC000]),
    ("victron-gx-vebus", "input_current_limit_a", 16.0, [160]),
    ("alfen-ng9xx", "max_current_a", 16.0, f32(16.0)),
    ("nibe-s-series", "heating_offset", -3, [0xFFFD]),
    ("nibe-f-series", "heat_offset", -3, [0xFFFD]),
    ("nibe-f-series", "hot_water_comfort_mode", "luxury", [2]),
    ("nibe-s-series", "room_setpoint_c", 21.5, [215]),
    ("stiebel-eltron-isg", "comfort_temperature_hk1_c", 21.5, [215]),
    ("stiebel-eltron-isg", "eco_temperature_dhw_c", 45.0, [450]),
]


@pytest.mark.parametrize(("map_id", "point", "value", "regs"), WRITES,
                         ids=[f"{w[0]}:{w[1]}" for w in WRITES])
def test_a_documented_write(map_id: str, point: str, value: Any, regs: list[int]) -> None:
    m = maps.builtin(map_id)
    assert m.encode(point, value) == regs


def test_the_em24_version_codes_are_read_one_word_a_request() -> None:
    for map_id in ("carlo-gavazzi-em21", "carlo-gavazzi-em24"):
        plan = maps.builtin(map_id).plan("identity")
        assert [(r.address, r.count) for r in plan] == [(0x0302, 1), (0x0303, 1)]
