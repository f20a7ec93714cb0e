"""Every map pymb ships beside the CoolPro and the hub, read back through
``pymb simulate`` (no ``--map``: a shipped map's id is a device type) with
``pymb read``: each point with an ``example`` reads that example, every
other point reads a value; a map with ``[[identify]]`` rules is what ``pymb
scan`` names at that address."""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from typing import Any

import pytest
from conftest import run_pymb

from pymb import maps
from pymb.devices.mapspec import TYPED_VIEWS
from pymb.maps import Point
from pymb.sim import SimulatorProcess

SHIPPED = [i for i in maps.builtin_ids() if i not in TYPED_VIEWS]


def same(p: Point, got: Any, want: Any) -> bool:
    if isinstance(want, list):
        return isinstance(got, list) and all(same(p, g, w) for g, w in zip(got, want,
                                                                          strict=True))
    if isinstance(want, str) and p.values:
        want = {name: raw for raw, name in p.values.items()}[want]
    if isinstance(want, bool) or isinstance(got, bool):
        return bool(got) == bool(want)
    if isinstance(want, float) or isinstance(got, float):
        # an f32 holds about 7 digits
        return isinstance(got, (int, float)) and math.isclose(got, want, rel_tol=1e-6,
                                                              abs_tol=1e-9)
    return bool(got == want)


def _addresses() -> dict[str, int]:
    """An address of its own for each shipped map on one bus: its default
    address unless a map with a narrower range took it, else the first free
    one its range allows."""
    taken: dict[int, str] = {}
    out: dict[str, int] = {}
    for map_id in sorted(SHIPPED, key=lambda i: (maps.builtin(i).device.addresses[1]
                                                 - maps.builtin(i).device.addresses[0], i)):
        dev = maps.builtin(map_id).device
        low, high = dev.addresses
        free = [a for a in [dev.default_address, *range(max(low, 1), high + 1)]
                if a not in taken]
        out[map_id] = free[0]
        taken[free[0]] = map_id
    return out


@pytest.fixture(scope="module")
def bus() -> Iterator[tuple[SimulatorProcess, dict[str, int]]]:
    """Every shipped map's simulated device, each at an address of its own, on
    one simulated bus: one ``pymb simulate`` for the module instead of one a map."""
    addresses = _addresses()
    with SimulatorProcess([f"{i}:{a}" for i, a in addresses.items()], quiet=True) as sim:
        yield sim, addresses


@pytest.mark.parametrize("map_id", SHIPPED)
def test_a_shipped_map_reads_back_through_the_simulator(
        map_id: str, bus: tuple[SimulatorProcess, dict[str, int]]) -> None:
    m = maps.builtin(map_id)
    sim, addresses = bus
    address = addresses[map_id]
    r = run_pymb("read", f"{map_id}:{address}", "--port", sim.port, "--json")
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    readable = [p for p in m.points.values() if p.access != "w"]
    assert list(doc["values"]) == [p.name for p in readable]
    for p in readable:
        got, state = doc["values"][p.name], doc["states"][p.name]
        if p.example is not None:
            want = p.example if not p.block or isinstance(p.example, list) else [
                p.example] * p.channels
            assert same(p, got, want), (p.name, got, p.example)
        states = state if isinstance(state, list) else [state]
        assert set(states) == {"value"}, (p.name, state)
    if m.identify:
        r = run_pymb("scan", "--port", sim.port, "--range", str(address))
        assert r.returncode == 0, r.stderr
        first = r.stdout.splitlines()[0]
        assert first.split()[0] == str(address), r.stdout
        # the map itself, or one whose rules are as specific and hold too
        # (then the line names the others)
        also = first.split("the identify rules of ")[-1].split(" hold too")[0] \
            if "hold too" in first else ""
        assert first.split()[1] == map_id or map_id in also.split(", "), r.stdout
