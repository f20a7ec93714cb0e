"""The read planner: limits, exact coverage, never worse than naive."""

from __future__ import annotations

from collections.abc import Callable, Iterable

import pytest
import reference as ref
from hypothesis import given, settings
from hypothesis import strategies as st

from pymb.devices import HUB
from pymb.devices.hub import full_sweep_spans
from pymb.logger import BusConfig, DeviceConfig
from pymb.maps.planner import Item, Known, Limits, Line, ReadPlan, plan_points
from pymb.wire import read_time


def plan_reads(wanted: Iterable[int], baudrate: int, *,
               readable: Callable[[int], bool] = lambda a: True,
               turnaround: float = 0.0, bits_per_char: int = 10) -> ReadPlan:
    """The planner's plan for one input register at each ``wanted`` address,
    where ``readable(address)`` says whether a register nobody asked for may be
    read (bridged)."""
    w = sorted(set(wanted))
    items = [Item(str(a), "input", a, 1) for a in w]
    gaps = [a for k in range(len(w) - 1) for a in range(w[k] + 1, w[k + 1]) if readable(a)]
    known = {"input": Known(((a, a + 1) for a in w), readable=((a, a + 1) for a in gaps))}
    return plan_points(items, Line(baudrate, bits_per_char, turnaround), Limits(),
                       known=known if w else {})


def covered(spans: tuple[tuple[int, int], ...]) -> set[int]:
    return {a for start, n in spans for a in range(start, start + n)}


@settings(max_examples=150, deadline=None)
@given(
    wanted=st.sets(st.integers(31, 730), min_size=1, max_size=300),
    holes=st.sets(st.integers(31, 730), max_size=100),
    baud=st.sampled_from([1200, 9600, 19200, 115200]),
    turnaround=st.sampled_from([0.0, 0.002, 0.02]),
)
def test_plan_limits_coverage_and_cost(wanted: set[int], holes: set[int], baud: int,
                                       turnaround: float) -> None:
    holes -= wanted
    plan = plan_reads(wanted, baud, readable=lambda a: a not in holes, turnaround=turnaround)
    assert all(1 <= n <= 125 for _, n in plan.spans)
    on_wire = covered(plan.spans)
    assert wanted <= on_wire  # covers everything asked
    assert not (on_wire & holes)  # never reads what the device may not have
    starts = [a for a, _ in plan.spans]
    assert starts == sorted(starts)
    assert sum(n for _, n in plan.spans) == len(on_wire)  # no overlap
    assert plan.predicted_s <= plan.naive_s + 1e-12
    assert abs(plan.predicted_s - sum(read_time(n, baud, turnaround=turnaround)
                                      for _, n in plan.spans)) < 1e-9


def test_full_sweep_is_six_requests_like_the_reference_plan() -> None:
    everything = range(HUB.points["temperature_c"].address, HUB.points["temperature2_c"].end)
    plan = plan_reads(everything, 9600)
    assert len(plan.spans) == 6
    assert plan.registers == 700
    ref_plan = ref.hub_sweep_spans(0, 100)
    assert len(ref_plan) == 6
    assert sum(n for _, n in ref_plan) == 700
    assert plan.spans == tuple(ref_plan)
    assert plan.predicted_s == pytest.approx(plan.naive_s)


def test_reference_plan_skips_missing_blocks_and_short_hubs() -> None:
    # Firmware V2.18: no voltage, RSSI or second temperature (blocks 4..6).
    assert ref.hub_sweep_spans(0b1110000, 100) == [(31, 125), (156, 125), (281, 125),
                                                   (406, 25)]
    # V1.07: 50 channels of temperature and humidity only.
    assert ref.hub_sweep_spans(0b1111100, 50) == [(31, 50), (131, 50)]


def test_twelve_channels_merge_gaps_when_cheaper() -> None:
    # 12 channels in use, temperature and humidity: at 9600 bit/s reading the
    # 88 registers between the two runs costs more than a second request.
    wanted = [HUB.points[b].address_of(c) for b in ("temperature_c", "humidity_pct")
              for c in range(1, 13)]
    slow = plan_reads(wanted, 9600, turnaround=0.0)
    assert slow.spans == ((31, 12), (131, 12))
    # At 115200 bit/s with a device that takes 20 ms to answer, one request
    # (88 extra registers: 15 ms of wire) is cheaper than two.
    slow_device = plan_reads(wanted, 115200, turnaround=0.02)
    assert slow_device.spans == ((31, 112),)
    assert slow_device.predicted_s < slow_device.naive_s
    assert "registers 31..142" in slow_device.explain()


def test_nothing_wanted_is_no_request() -> None:
    assert plan_reads([], 9600).spans == ()


def test_explain_agrees_with_the_plans_total_on_any_line() -> None:
    # 8E1: 11 bits a character; every line of explain() and its total use them.
    plan = plan_reads([31, 32, 40, 131], 19200, turnaround=0.002, bits_per_char=11)
    lines = plan.explain().splitlines()
    per_request = [float(line.split(")")[-1].split()[0]) for line in lines[1:-1]]
    assert len(per_request) == len(plan.spans)
    assert abs(sum(per_request) - plan.predicted_s * 1e3) < 0.01 * len(per_request)
    assert f"predicted {plan.predicted_s * 1e3:.2f} ms" in lines[-1]


def test_the_loggers_wire_time_prices_the_sweep_the_c_core_plans() -> None:
    # 50 channels: seven reads of 50 (the blocks are 100 apart), not three of 125.
    assert full_sweep_spans(50) == [(31 + 100 * b, 50) for b in range(7)]
    hub = DeviceConfig("hub", 1, options={"channels": 50})
    bus = BusConfig("b", "/dev/null", baud=19200, parity="E", devices=[hub])
    assert bus.wire_time(hub) == pytest.approx(7 * read_time(50, 19200, bits=11))
