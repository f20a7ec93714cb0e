"""The shipped maps: the hub map decodes registers exactly as the hub's
facade and the pure-Python reference of [HUB] (tests/reference.py) do, the
CoolPro map as the reference of [CP] does; each names its source.
(tests/sim/test_shipped_maps_sim.py reads the others back through ``pymb
simulate``.)"""

from __future__ import annotations

import math
import random
from array import array

import pytest
import reference as ref

from pymb import maps
from pymb.devices import decode_hub
from pymb.devices.coolpro import CoolProStatus
from pymb.devices.hub import State

UNIDENTIFIABLE = ("abb-acs580", "danfoss-fc", "siemens-v20")
BLOCKS = ("temperature_c", "humidity_pct", "pressure_temperature_c", "pressure_kpa",
          "voltage_mv", "rssi_dbm", "temperature2_c")
MARKERS = (0xFFFF, 0x8000, 0x00FF, 0x8001, 0x7FFF, 0)


def hub_registers(rng: random.Random) -> array[int]:
    return array("H", [rng.choice(MARKERS) if rng.random() < 0.2 else rng.randrange(0x10000)
                       for _ in range(700)])


@pytest.mark.parametrize(("unit", "channels"), [(0.1, 100), (1, 100), (0.1, 50), (1, 7)])
def test_hub_map_reads_what_the_reference_and_the_facade_read(unit: float,
                                                               channels: int) -> None:
    hub = maps.builtin("hub").configure(humidity_unit=unit, channels=channels)
    names = {"offline": State.OFFLINE, "no_sensor": State.NO_SENSOR, "value": State.VALUE}
    ref_names = {ref.OFFLINE: "offline", ref.NO_SENSOR: "no_sensor", ref.VALUE: "value"}
    rng = random.Random(f"{unit}/{channels}")
    for _ in range(20):
        regs = hub_registers(rng)
        today = decode_hub(regs, unit, channels=channels)
        d = maps.Decoder(hub)
        assert d.address == 31
        values, states = d.read(regs), d.states()
        for b, name in enumerate(BLOCKS):
            ours = values[name]
            assert isinstance(ours, list)
            theirs = list(getattr(today, name))
            assert len(ours) == len(theirs) == channels
            for c, (v, t, s, ts) in enumerate(
                    zip(ours, theirs, states[name], today.states(name), strict=True)):
                assert names[s] == ts
                want_state, want = ref.hub_value(b, regs[100 * b + c], unit)
                assert s == ref_names[want_state]
                assert (v is None) if math.isnan(want) else (v == want), (name, c, v, want)
                if math.isnan(t):
                    assert v is None
                else:  # the same double, -0.0 included
                    assert isinstance(v, int | float), (name, v)
                    assert v == t, (name, v, t)
                    assert math.copysign(1, v) == math.copysign(1, t), (name, v, t)


def test_coolpro_map_reads_what_the_reference_reads() -> None:
    cp = maps.builtin("coolpro")
    telemetry = maps.Decoder(cp, [p.name for p in cp.points.values() if p.group == "telemetry"])
    identity = maps.Decoder(cp, [p.name for p in cp.points.values() if p.group == "identity"])
    assert (telemetry.address, telemetry.count, identity.address, identity.count) == \
        (0, 8, 100, 8)
    rng = random.Random(7)
    for _ in range(500):
        regs = array("H", [rng.randrange(0x10000) for _ in range(8)])
        vin, iin, vout, iout, temp, uptime, status = ref.coolpro_telemetry(list(regs))
        got = telemetry.read(regs)
        assert got == {"input_voltage_v": vin, "input_current_a": iin,
                       "output_voltage_v": vout, "output_current_a": iout,
                       "temperature_c": temp, "uptime_s": uptime, "status": status}
        assert cp.flag_names("status", status) == [
            f.name for f in CoolProStatus if f in CoolProStatus(status)]
        serial, hw, major, minor, patch, made = ref.coolpro_identity(list(regs))
        assert identity.read(regs) == {
            "serial_number": serial, "hardware_revision": hw, "firmware_major": major,
            "firmware_minor": minor, "firmware_patch": patch, "manufactured": made}


def test_every_shipped_map_names_its_source() -> None:
    from importlib import resources

    for ident in maps.builtin_ids():
        text = (resources.files("pymb.maps") / "builtin" / f"{ident}.toml").read_text()
        assert text.startswith("#")
        assert "Source:" in text.split("schema")[0], ident
        m = maps.builtin(ident)
        assert m.id == ident
        # the hub is recognised by its sweep; a drive's control and status words hold
        # nothing that tells it from another device's registers
        assert m.identify or ident in ("hub", *UNIDENTIFIABLE), ident


def test_the_docs_list_every_shipped_map() -> None:
    from pathlib import Path

    doc = (Path(__file__).resolve().parents[2] / "docs" / "maps.md").read_text()
    table = doc[doc.index("## Shipped maps"):doc.index("## What pymb decides")]
    listed = [line.split("`")[1] for line in table.splitlines() if line.startswith("| `")]
    assert listed == ["coolpro", "hub", "eastron-sdm120", "eastron-sdm630", "generic-vfd"]
    assert set(listed) <= set(maps.builtin_ids())  # the rest: map-devices.md's library


def test_the_devices_hub_and_coolpro_are_the_shipped_maps() -> None:
    from pymb.devices import COOLPRO, HUB
    from pymb.devices.coolpro import COOLPRO_BAUD_RATES
    from pymb.devices.hubreading import BLOCKS, CHANNELS

    assert HUB is maps.builtin("hub")
    assert COOLPRO is maps.builtin("coolpro")
    assert [b.name for b in BLOCKS] == list(HUB.points)
    assert CHANNELS == HUB.options["channels"] == 100
    assert COOLPRO_BAUD_RATES == (9600, 19200, 38400, 57600, 115200)
    assert COOLPRO.timing.turnaround == 0.008
    # the humidity's "no sensor" marker and scale follow the channel's unit
    for unit, marker in ((1, 0x00FF), (0.1, 0x8000)):
        humidity = HUB.configure(humidity_unit=unit).points["humidity_pct"]
        assert dict(humidity.markers) == {0xFFFF: "offline", marker: "no_sensor"}
        assert humidity.scale == unit
