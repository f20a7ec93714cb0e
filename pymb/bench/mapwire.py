"""The bench's ``maps`` section, over the wire: a device read through its map
against the dedicated facade, pair by pair in the same run.

One simulator process (the ``sweep`` section's: the hub and the CoolPro at
115200 8N1 over a pty, no wire emulation) and one :class:`~pymb.RtuClient`
in this process carry both sides of each pair:

``hub``        ``MapDevice(client, maps.builtin("hub"), address=...)``
               reading every block (``read_into``: the values in the
               decoder's arrays, no dict) against
               ``SensorHub.read_all(into=r)``: 700 registers in 6 requests,
               decoded.
``telemetry``  the CoolPro's ``telemetry`` group through
               ``maps.builtin("coolpro")`` against
               ``CoolPro.read_telemetry()``.

The CoolPro map's ``turnaround`` (the real device's ~8 ms) is set to 0 for
the pair, as the simulator's ``gap=0`` is: software cost only, as the
dedicated read (which leaves the gap to the caller) has it.

Rounds are interleaved (the side that goes first alternates), each side
warmed by as many untimed reads before its timed batch; per round the CPU
(``time.process_time_ns``, this process: the simulator is another) and the
median wall time per read, and the ratio map/dedicated of that round.
Reported: the medians over the rounds. The pairs are cheap (a round of the
hub's is 160 reads, well under 0.1 s), so they take :data:`ROUNDS_PER_ROUND`
times the sweep section's rounds (100 by default): on a busy machine the
median of 20 rounds moves by several percent from run to run, the median of
100 by about one.
"""

from __future__ import annotations

import dataclasses
import statistics
import time
from collections.abc import Callable
from typing import Any

from pymb.bench.options import SEED, SOFTWARE_BAUD, Options
from pymb.bench.procs import Children
from pymb.bench.race import _software_devices
from pymb.bench.table import Table, fmt_time, fmt_x
from pymb.bench.worker import CP_SLAVE, HUB_SLAVE

__all__ = ["ROUNDS_PER_ROUND", "TARGET_X", "run_section", "table", "targets"]

TARGET_X = 1.0  #: the map's CPU per read, as a multiple of the dedicated read's
ROUNDS_PER_ROUND = 5  #: rounds of each pair per round of the sweep comparison
_TIMEOUT = 2.0

#: (key, what) of each pair, in the report's order
PAIRS = (("hub", "hub: every block (700 registers, 6 requests)"),
         ("telemetry", "CoolPro telemetry (8 registers)"))


def _batch(fn: Callable[[], object], n: int) -> tuple[float, float]:
    """``n`` untimed calls, then ``n`` timed: (CPU us per call, median wall us)."""
    for _ in range(n):
        fn()
    walls = []
    cpu0 = time.process_time_ns()
    for _ in range(n):
        t0 = time.perf_counter_ns()
        fn()
        walls.append(time.perf_counter_ns() - t0)
    cpu = (time.process_time_ns() - cpu0) / n / 1e3
    return cpu, statistics.median(walls) / 1e3


def _pair(via_map: Callable[[], object], dedicated: Callable[[], object], rounds: int,
          n: int) -> dict[str, Any]:
    rows: list[tuple[float, float, float, float]] = []
    for r in range(rounds):
        if r % 2:
            dc, dw = _batch(dedicated, n)
            mc, mw = _batch(via_map, n)
        else:
            mc, mw = _batch(via_map, n)
            dc, dw = _batch(dedicated, n)
        rows.append((mc, mw, dc, dw))
    return {
        "map_cpu_us": statistics.median(r[0] for r in rows),
        "map_wall_us": statistics.median(r[1] for r in rows),
        "dedicated_cpu_us": statistics.median(r[2] for r in rows),
        "dedicated_wall_us": statistics.median(r[3] for r in rows),
        "cpu_x": statistics.median(r[0] / r[2] for r in rows),
        "wall_x": statistics.median(r[1] / r[3] for r in rows),
        "round_cpu_x": [r[0] / r[2] for r in rows],
    }


def run_section(opts: Options, children: Children) -> dict[str, Any]:
    """The two pairs over one simulator (see the module); JSON-able."""
    from pymb import RtuClient, maps
    from pymb.devices import CoolPro, MapDevice, SensorHub

    plan = opts.plan
    rounds, n = ROUNDS_PER_ROUND * plan.rounds, plan.sweeps
    opts.say("maps: reads through the map against the dedicated reads, over a pty")
    sim = children.sims([[*_software_devices(), "--seed", str(SEED)]])[0]
    client = RtuClient(sim.port, SOFTWARE_BAUD, timeout=_TIMEOUT)
    try:
        client.connect()
        hub = SensorHub(client, HUB_SLAVE)
        hub_map = MapDevice(client, maps.builtin("hub"), address=HUB_SLAVE)
        cp = CoolPro(client, CP_SLAVE)
        m = maps.builtin("coolpro")
        m = dataclasses.replace(m, timing=dataclasses.replace(m.timing, turnaround=0.0))
        cp_map = MapDevice(client, m, address=CP_SLAVE)
        reading = hub.read_all()
        _same_hub(hub_map)
        for _ in range(3):  # the simulated CoolPro's values move: a read may straddle a step
            t = cp.read_telemetry()
            got = cp_map.read(group="telemetry")
            if got["input_voltage_v"] == t.input_voltage_v and got["status"] == int(t.status):
                break
        else:
            raise RuntimeError(f"the CoolPro map reads {got}, the facade {t}")

        def dedicated_hub() -> None:
            hub.read_all(into=reading)

        def map_hub() -> None:
            hub_map.read_into()

        def map_cp() -> None:
            cp_map.read_into(group="telemetry")

        out: dict[str, Any] = {"rounds": rounds, "per_round": n, "baud": SOFTWARE_BAUD}
        opts.say(f"maps: hub through its map vs read_all, {rounds} rounds")
        out["hub"] = _pair(map_hub, dedicated_hub, rounds, n)
        opts.say(f"maps: CoolPro telemetry through its map vs read_telemetry, {rounds} rounds")
        out["telemetry"] = _pair(map_cp, cp.read_telemetry, rounds, 2 * n)
        return out
    finally:
        client.close()
        children.stop(sim)


def _same_hub(hub_map: Any) -> None:
    """The map's read of the hub is the dedicated decoder's, on the same
    registers (the simulator's values drift between two reads)."""
    from pymb.devices.hub import decode_hub

    got = hub_map.read_group()
    want = decode_hub(got.registers).as_dict()
    if dict(got.values) != want:
        raise RuntimeError("the hub read through its map differs from the dedicated "
                           "decoder's reading of the same registers")


def targets(section: dict[str, Any]) -> list[tuple[str, str, float, str, bool]]:
    """This part's target: (what, goal, measured, unit, met)."""
    x = section["hub"]["cpu_x"]
    return [("the hub read through its map, CPU per read against SensorHub.read_all "
             "(pair by pair, same run)", f"<= {TARGET_X:.2f}x", x, "x", x <= TARGET_X)]


def table(section: dict[str, Any]) -> Table:
    """The pairs as a report table."""
    rows = []
    for key, what in PAIRS:
        p = section[key]
        rows.append([what, fmt_time(p["map_cpu_us"]), fmt_time(p["dedicated_cpu_us"]),
                     fmt_x(p["cpu_x"]), fmt_time(p["map_wall_us"]),
                     fmt_time(p["dedicated_wall_us"]), fmt_x(p["wall_x"])])
    return Table(
        "Maps over the wire: MapDevice against the dedicated facade",
        f"one simulator over a pty at {section['baud']} (no wire emulation), one client; "
        f"{section['rounds']} interleaved rounds, {section['per_round']} reads per side "
        "(telemetry: twice as many), medians; ratios map/dedicated paired per round",
        ["read", "map CPU", "dedicated CPU", "CPU ratio", "map wall", "dedicated wall",
         "wall ratio"],
        rows, [False, True, True, True, True, True, True],
        [f"target: the hub through its map at ≤ {TARGET_X:.2f}x the dedicated read's CPU"])
