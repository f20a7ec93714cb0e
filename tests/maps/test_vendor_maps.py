"""Every shipped device map, as a user meets it: it loads, says where its
facts come from, plans every group within its own limits, and a value of
every point set in the map simulator comes back decoded through a real
Modbus TCP read by :class:`pymb.devices.MapDevice`. (The documents' own
decodings of particular maps are in test_vendor_examples.py.)"""

from __future__ import annotations

import math
import random
import string
from dataclasses import replace
from types import MappingProxyType
from typing import Any

import pytest

import pymb
from pymb import maps
from pymb.devices import MapDevice
from pymb.devices.mapspec import TYPED_VIEWS
from pymb.maps import Map, Point
from pymb.maps.types import TYPES
from pymb.sim import Simulator
from pymb.sim.mapsim import MapSimDevice

SHIPPED = [i for i in maps.builtin_ids() if i not in TYPED_VIEWS]


def views(m: Map) -> set[str]:
    """The points that share registers with a wider point declared before them."""
    seen: dict[tuple[str, int], str] = {}
    out: set[str] = set()
    for p in m.points.values():
        regs = [(p.table, a) for c in range(1, p.channels + 1)
                for a in range(p.address_of(c), p.address_of(c) + p.count)]
        if any(r in seen for r in regs):
            out.add(p.name)
        for r in regs:
            seen.setdefault(r, p.name)
    return out


def random_value(p: Point, rng: random.Random) -> Any:
    """A value ``p`` can hold, in engineering units, exactly representable."""
    info = TYPES[p.type]
    if p.values:
        return rng.choice(list(p.values))
    if info.family in ("bool", "bit"):
        return rng.random() < 0.5
    if info.family == "string":
        width = 2 * p.count if p.string_bytes == "both" else p.count
        return "".join(rng.choice(string.ascii_letters + string.digits)
                       for _ in range(rng.randrange(1, width + 1)))
    if info.family == "raw":
        return [rng.randrange(0x10000) for _ in range(p.count)]
    if info.family == "float":
        lo, hi = p.valid if p.valid is not None else (-1e5, 1e5)
        return rng.uniform(lo, hi)
    raw_lo, raw_hi = info.raw_range()
    if p.type == "bits" and p.width is not None:
        raw_lo, raw_hi = 0, 2 ** p.width - 1
    scale, offset = p.scale or 1.0, p.offset or 0.0
    if p.valid is not None:
        a, b = sorted(((p.valid[0] - offset) / scale, (p.valid[1] - offset) / scale))
        raw_lo, raw_hi = max(raw_lo, math.ceil(a)), min(raw_hi, math.floor(b))
    while True:
        raw = rng.randint(raw_lo, raw_hi)
        if raw not in p.markers:
            break
    if p.scale is None and p.offset is None:
        return raw
    return raw * scale + offset


def same(p: Point, got: Any, want: Any) -> bool:
    if isinstance(got, str) and p.values:  # a write gives back the value's name
        got = {label: raw for raw, label in p.values.items()}.get(got, got)
    if isinstance(want, bool) or isinstance(got, bool):
        return bool(got) == bool(want)
    if isinstance(want, float) or isinstance(got, float):
        tol = 1e-6 if TYPES[p.type].family == "float" else 1e-9
        return isinstance(got, (int, float)) and math.isclose(got, want, rel_tol=tol,
                                                              abs_tol=1e-9)
    return bool(got == want)


@pytest.mark.parametrize("map_id", SHIPPED)
def test_a_shipped_map_names_its_device_and_document(map_id: str) -> None:
    m = maps.builtin(map_id)
    d = m.device
    for field in (d.manufacturer, d.model, d.description, d.ref):
        assert field, map_id
    # what pymb scan would name this map: a peer's registers must not pass for it
    assert m.identify or map_id in ("abb-acs580", "danfoss-fc", "siemens-v20"), map_id
    assert m.groups, map_id
    for p in m.points.values():
        assert p.description, (map_id, p.name)
        assert p.ref, (map_id, p.name)
        if p.access != "w":
            assert p.example is not None, (map_id, p.name)
        if p.writable and TYPES[p.type].family not in ("bool", "bit", "string", "raw") \
                and not p.values:
            assert p.valid is not None, (map_id, p.name, "a writable number needs `valid`")
        if p.writable:
            assert p.max_writes_per_hour, (map_id, p.name, "a writable point needs a budget")


@pytest.mark.parametrize("map_id", SHIPPED)
def test_every_group_plans_within_the_maps_limits(map_id: str) -> None:
    m = maps.builtin(map_id)
    lim = m.limits
    declared: dict[str, set[int]] = {}
    for p in m.points.values():
        for c in range(1, p.channels + 1):
            declared.setdefault(p.table, set()).update(
                range(p.address_of(c), p.address_of(c) + p.count))
    for group in [*m.groups, None]:  # None: every readable point
        names = [p.name for p in m.points.values()
                 if group in (p.group, None) and p.access != "w"]
        if not names:
            continue
        plan = m.plan(group)
        for r in plan:
            limit = lim.max_bits if r.table in ("coil", "discrete") else lim.max_registers
            assert 1 <= r.count <= limit, (map_id, group, r)
            for table, first, last, most in getattr(lim, "ranges", ()):  # per-range limits
                if r.table == table and r.address <= last and first < r.address + r.count:
                    assert r.count <= most, (map_id, group, r, (first, last, most))
            assert r.address + r.count <= 0x10000
            for a in range(r.address, r.address + r.count):
                inside = any(lo <= a <= hi for lo, hi in lim.readable.get(r.table, ()))
                assert a in declared.get(r.table, set()) or inside or lim.max_gap, \
                    (map_id, group, r, a)
        for name in names:  # a point is read whole, by one request
            p = m.points[name]
            for c in range(1, p.channels + 1):
                a = p.address_of(c)
                assert any(r.table == p.table and r.address <= a and
                           a + p.count <= r.address + r.count for r in plan), (map_id, name)


@pytest.mark.parametrize("map_id", SHIPPED)
def test_values_set_in_the_simulator_read_back_over_tcp(map_id: str) -> None:
    m = maps.builtin(map_id)
    rng = random.Random(map_id)
    skip = views(m)
    want: dict[str, Any] = {}
    points = {}
    for name, p in m.points.items():
        if name in skip:
            points[name] = replace(p, example=None)
            continue
        value = random_value(p, rng)
        want[name] = value
        points[name] = replace(p, example=[value] * p.channels if p.block else value)
    served = replace(m, points=MappingProxyType(points))
    address = m.device.default_address
    dev = MapSimDevice(served, address, dynamic=False)
    with Simulator([dev], transport="tcp") as sim, \
            pymb.TcpClient(sim.host, sim.tcp_port, slave=address, timeout=5.0) as client:
        device = MapDevice(client, m, address=address)
        got = device.read()
        for name, value in want.items():
            p = m.points[name]
            if p.access == "w":
                continue
            if p.block:
                channels = got[name]
                assert isinstance(channels, list), (map_id, name)
                assert all(same(p, g, value) for g in channels), (map_id, name, channels, value)
            else:
                assert same(p, got[name], value), (map_id, name, got[name], value)
            assert device.states[name] in ("value", ["value"] * p.channels), (map_id, name)
        for name in skip:  # a view reads what its registers say
            p = m.points[name]
            if p.access == "w" or p.block:
                continue
            raw = client.read_holding_registers(p.address, p.count) \
                if p.table == "holding" else client.read_input_registers(p.address, p.count)
            assert got[name] == m.decode(name, list(raw)), (map_id, name)


def library_rows() -> list[str]:
    """docs/map-devices.md's library table as it must read: one row a shipped map."""
    rows = []
    for ident in SHIPPED:
        d = maps.builtin(ident).device
        rows.append(f"| `{ident}` | {d.manufacturer} {d.model} | {d.ref} |")
    return rows


def test_the_device_library_table_lists_every_shipped_map() -> None:
    from pathlib import Path

    doc = (Path(__file__).resolve().parents[2] / "docs" / "map-devices.md").read_text()
    section = doc[doc.index("## The device library"):]
    listed = [line for line in section.splitlines() if line.startswith("| `")]
    assert listed == library_rows(), "the table should read:\n" + "\n".join(library_rows())


WRITABLE = [(i, p.name) for i in SHIPPED for p in maps.builtin(i).points.values() if p.writable]


@pytest.mark.parametrize(("map_id", "name"), WRITABLE, ids=[f"{i}:{n}" for i, n in WRITABLE])
def test_a_writable_point_takes_its_range_and_refuses_beyond_it(map_id: str, name: str) -> None:
    m = maps.builtin(map_id)
    p = m.points[name]
    rng = random.Random(f"{map_id}:{name}")
    value = random_value(p, rng)
    address = m.device.default_address
    with Simulator([MapSimDevice(m, address, dynamic=False)], transport="tcp") as sim, \
            pymb.TcpClient(sim.host, sim.tcp_port, slave=address, timeout=5.0) as client:
        device = MapDevice(client, m, address=address)
        after = device.write(name, value)
        if p.access == "rw":
            assert same(p, after, value), (map_id, name, after, value)
            assert same(p, device.read(name)[name], value)
        else:
            assert after is None
        if p.valid is not None:
            lo, hi = p.valid
            for outside in (lo - abs(lo) - 1, hi + abs(hi) + 1):
                with pytest.raises(pymb.InvalidArgument):
                    device.write(name, outside)
        elif p.values:
            with pytest.raises(pymb.InvalidArgument):
                device.write(name, max(p.values) + 1)
        assert p.max_writes_per_hour is not None
        assert 1 <= p.max_writes_per_hour <= 3600


@pytest.mark.parametrize("seed", [1, 4, 7])
def test_no_vendor_map_passes_for_the_hub_or_the_coolpro(seed: int) -> None:
    from pymb.devices.mapspec import match_map
    from pymb.sim import SimClock
    from pymb.sim.simulator import make_device

    devices = {d.address: d for d in (make_device(spec, seed=seed, clock=SimClock(0.0))
                                      for spec in ("hub:250", "coolpro"))}

    def ask(address: int, function: int, data: bytes) -> bytes | int | None:
        reply = devices[address].handle(bytes([function]) + data)
        if reply is None:
            return None
        return reply[1] if reply[0] & 0x80 else reply[1:]

    for ident in SHIPPED:
        m = maps.builtin(ident)
        for address in devices:
            assert match_map(ask, address, {ident: m}) is None, (ident, address)
