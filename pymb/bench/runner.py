"""What ``pymb bench`` measures, and how.

Sections (each can be chosen with ``--sections``):

``micro``    in-process: CRC-16 of a 255-byte frame and the decode of 700
             hub registers, pymb (C) against pure Python (timeit, median).
``plan``     in-process: planning the reads of a 1,000-point map
             (:mod:`pymb.bench.planbench`).
``maps``     in-process: decoding a 100-point f32 map in one C call
             (:mod:`pymb.bench.mapbench`); then the hub and the CoolPro
             read through their maps against the dedicated facades, over
             the ``sweep`` section's simulator (:mod:`pymb.bench.mapwire`).
``sweep``    the workload: one sweep of the hub's 700 registers (6 requests,
             decoded) and one CoolPro telemetry read, per contender, each in
             its own process against its own simulator process over a pty,
             with no wire emulation (the line is set to 115200 8N1, the
             CoolPro's gap to 0): pure software cost. Rounds are interleaved
             (round-robin, the order rotating), results are medians, ratios
             are to the C program, paired per round.
``wire``     the simulator emulating 9600 and 115200 baud: pymb's sweep (and
             the C program's, the floor of that emulation) against the
             theoretical wire time of the frames from
             :func:`pymb.wire.read_time`; and the CoolPro's
             telemetry with its real ~8 ms gap.
``scaling``  1, 2, 4 and 8 buses swept in parallel threads at emulated
             115200: aggregate sweeps per second and the process's CPU.
``fleet``    samples through a local mosquitto: pymb's forwarder against a
             plain paho publisher at QoS 0 and QoS 1 (throughput, latency,
             samples lost and duplicated across a 3 s broker outage); see
             :mod:`pymb.bench.fleet`.
``aio``      :mod:`pymb.aio` against the blocking calls and pymodbus's async
             client: per-call wall and CPU, and the event loop's lag with 8
             hubs polled flat out (:mod:`pymb.bench.aiobench`).
``logger``   ``pymb log``'s cost on top of the bare read, pair by pair, the
             database on disk: CPU and bytes per sample, report by exception,
             and the storage layouts compared (:mod:`pymb.bench.logbench`).
``gateway``  10, 100 and 300 Modbus TCP devices polled flat out by one
             process, every poll stored in SQLite: values per CPU-second,
             CPU per poll, RSS, threads; pymb's fan-out loop against a
             thread per connection and pymodbus's async client
             (:mod:`pymb.bench.gatebench`).
``serve``    a read direct and through ``pymb serve`` (plain and TLS): the
             latency it adds and its CPU per read (:mod:`pymb.bench.servebench`;
             only when named).

Every simulator and worker is a child process stopped at the end, on error
and on Ctrl-C (and, through ``PR_SET_PDEATHSIG``, if the bench is killed).
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
import platform
import random
import statistics
import sys
import tempfile
import time
import timeit
from collections.abc import Callable
from typing import Any

import pymb
from pymb import _native
from pymb.bench import (
    aiobench,
    collectbench,
    fleet,
    gatebench,
    logbench,
    mapbench,
    mapwire,
    planbench,
    pure,
    servebench,
    soak,
    writebench,
)
from pymb.bench.options import (
    BUSES,
    QUICK_BUDGET,
    SECTIONS,
    SEED,
    SOFTWARE_BAUD,
    Options,
    Plan,
)
from pymb.bench.procs import ChildError, Children
from pymb.bench.race import (
    Lineup,
    RaceEntry,
    Reference,
    _same_values,
    _software_devices,
    _stop_all,
    hub_registers,
    race,
    summary,
    verify,
)
from pymb.bench.worker import CP_COUNT, CP_SLAVE, HUB_SLAVE, SPANS
from pymb.devices.hub import decode_hub
from pymb.devices.hubreading import HUB_REGISTERS
from pymb.sim import CoolProDevice, make_device
from pymb.wire import read_time

__all__ = [
    "SECTIONS",
    "Options",
    "Plan",
    "RaceEntry",
    "Reference",
    "hub_registers",
    "race",
    "run",
    "summary",
    "verify",
]


# -- sections -------------------------------------------------------------------------------


def run_micro(opts: Options) -> dict[str, Any]:
    """CRC-16 of 255 bytes and the decode of 700 registers: pymb vs pure Python."""
    opts.say("micro: CRC-16 and decode")
    rng = random.Random(SEED)
    frame = bytes(rng.randrange(256) for _ in range(255))
    regs = hub_registers()
    regs_list = list(regs)
    if pymb.crc16(frame) != pure.crc16(frame):
        raise RuntimeError("pymb.crc16 and the pure-Python CRC disagree")
    _same_values("micro decode", pure.decode_hub(regs_list), decode_hub(regs).values)
    repeat = opts.plan.micro_repeat

    def per_call(stmt: Callable[[], object]) -> float:
        t = timeit.Timer(stmt)
        once = max(t.timeit(10) / 10, 1e-8)
        number = max(10, int(opts.plan.micro_seconds / once))
        return statistics.median(t.repeat(repeat=repeat, number=number)) / number * 1e6

    crc = pymb.crc16
    rows: list[dict[str, Any]] = [
        {"name": "crc16", "what": "CRC-16 of a 255-byte frame",
         "pymb_us": per_call(lambda: crc(frame)),
         "python_us": per_call(lambda: pure.crc16(frame)),
         "pymb_call": "pymb.crc16(frame)", "python_call": "table-driven loop",
         "target_us": 1.0},
        {"name": "decode", "what": f"decode {HUB_REGISTERS} hub registers",
         "pymb_us": per_call(lambda: decode_hub(regs)),
         "python_us": per_call(lambda: pure.decode_hub(regs_list)),
         "pymb_call": "decode_hub(array('H'))", "python_call": "list comprehensions",
         "target_us": 3.0},
    ]
    for r in rows:
        r["speedup"] = r["python_us"] / r["pymb_us"]
    return {"repeat": repeat, "rows": rows}


def run_sweep(opts: Options, lineup: Lineup, children: Children) -> dict[str, Any]:
    """The workload, every contender side by side (pure software cost)."""
    plan = opts.plan
    entries = lineup.entries()
    runnable = [e for e in entries if e.status == "ok"]
    opts.say(f"sweep: starting {len(runnable)} simulators and contenders")
    sims = children.sims([[*_software_devices(), "--seed", str(SEED)] for _ in runnable])
    for e, sim in zip(runnable, sims, strict=True):
        lineup.start(e, sim.port, SOFTWARE_BAUD)
    for e in runnable:
        if e.status == "ok":
            verify(e, lineup.ref, children, telemetry=True)
    race(entries, "hub", "sweep", plan.rounds, plan.sweeps, plan.warm_sweeps, children, opts,
          "sweep: hub")
    race(entries, "telemetry", "tele", plan.rounds, plan.reads, plan.warm_reads, children,
          opts, "sweep: CoolPro telemetry")
    _stop_all(entries, sims, children)
    return {
        "baud": SOFTWARE_BAUD,
        "hub": summary(entries, "hub", plan.sweeps),
        "telemetry": summary(entries, "telemetry", plan.reads),
    }


def _theory_sweep(baud: int) -> float:
    return sum(read_time(count, baud) for _, count in SPANS)


def run_wire(opts: Options, lineup: Lineup, children: Children) -> dict[str, Any]:
    """Sweeps against the theoretical wire time, the simulator emulating the line."""
    plan = opts.plan
    coolpro = make_device("coolpro")
    assert isinstance(coolpro, CoolProDevice)
    gap = coolpro.gap
    rows: list[dict[str, Any]] = []
    setups = [(9600, plan.rounds_9600, 1, False),
              (115200, plan.wire_rounds, plan.sweeps_115200, True)]
    for baud, rounds, n, telemetry in setups:
        # --quick: pymb alone at 9600 (a sweep there takes 1.6 s of wire, the
        # C program's is the same wire), to fit its budget
        entries = lineup.entries(("pymb",) if opts.quick and baud == 9600 else ("pymb", "c"))
        runnable = [e for e in entries if e.status == "ok"]
        devices = [f"hub:{HUB_SLAVE},dynamic=0"] + ([f"coolpro:{CP_SLAVE}"] if telemetry else [])
        opts.say(f"wire: {baud} baud, {len(runnable)} contenders")
        sims = children.sims([[*devices, "--baud", str(baud), "--seed", str(SEED)]
                              for _ in runnable])
        for e, sim in zip(runnable, sims, strict=True):
            lineup.start(e, sim.port, baud)
        # No verification sweep: at 9600 one costs 1.6 s, the canaries are checked on
        # every sweep, and the sweep section verified both contenders' decoding.
        # --quick at 9600: no untimed sweep before the timed one (1.6 s each)
        race(entries, "hub", "sweep", rounds, n, 0 if baud < 19200 else 1, children, opts,
              f"wire: {baud} baud", settle=not (opts.quick and baud < 19200))
        theory = _theory_sweep(baud)
        for row in summary(entries, "hub", n)["rows"]:
            row.update(baud=baud, workload="hub sweep", theory_us=theory * 1e6)
            if "wall_us" in row:
                row["theory_x"] = row["wall_us"] / (theory * 1e6)
            rows.append(row)
        if telemetry:
            race(entries, "telemetry", "tele", rounds, 2 * n + 2, 2, children, opts,
                  f"wire: CoolPro with its {gap * 1e3:g} ms gap")
            t_theory = read_time(CP_COUNT, baud, turnaround=gap)
            for row in summary(entries, "telemetry", 2 * n + 2)["rows"]:
                row.update(baud=baud, workload=f"CoolPro telemetry, {gap * 1e3:g} ms gap",
                           theory_us=t_theory * 1e6)
                if "wall_us" in row:
                    row["theory_x"] = row["wall_us"] / (t_theory * 1e6)
                rows.append(row)
        _stop_all(entries, sims, children)
    return {"gap_ms": gap * 1e3, "rows": rows}


def run_scaling(opts: Options, children: Children) -> dict[str, Any]:
    """1, 2, 4, 8 buses in parallel threads of one pymb process, at emulated 115200."""
    baud = 115200
    plan = opts.plan
    opts.say(f"scaling: starting {max(BUSES)} simulators")
    sims = children.sims([[f"hub:{HUB_SLAVE},dynamic=0", "--baud", str(baud), "--seed",
                           str(SEED)] for _ in range(max(BUSES))])
    worker = children.start("scaling worker", [sys.executable, "-m", "pymb.bench.scale",
                                                   str(baud), *(s.port for s in sims)])
    line = worker.readline(60.0)
    if not line.startswith("ready"):
        raise ChildError(f"scaling worker: {line}")
    runs: dict[int, list[dict[str, Any]]] = {k: [] for k in BUSES}
    for rep in range(plan.scale_repeats):
        for k in BUSES:
            opts.say(f"scaling: {k} bus(es), {plan.scale_seconds:g} s "
                     f"({rep + 1}/{plan.scale_repeats})")
            runs[k].append(json.loads(worker.ask(f"run {k} {plan.scale_seconds}",
                                                 60.0 + plan.scale_seconds)))
    children.stop(worker)
    for s in sims:
        children.stop(s)
    rows = []
    for k in BUSES:
        rates = [sum(n / s for n, s in zip(r["sweeps"], r["spans"], strict=True) if s > 0)
                 for r in runs[k]]
        cpu = [r["cpu"] / r["wall"] for r in runs[k]]
        per = [r["cpu"] / max(1, sum(r["sweeps"])) for r in runs[k]]
        rows.append({"buses": k, "sweeps_per_s": statistics.median(rates),
                     "cpu_pct": 100 * statistics.median(cpu),
                     "cpu_per_sweep_us": 1e6 * statistics.median(per),
                     "runs": runs[k]})
    one = rows[0]["sweeps_per_s"]
    for r in rows:
        r["speedup"] = r["sweeps_per_s"] / one if one else math.nan
    theory = _theory_sweep(baud)
    return {"baud": baud, "seconds": plan.scale_seconds, "repeats": plan.scale_repeats,
            "theory_sweeps_per_s": 1 / theory, "rows": rows}


# -- the whole run ---------------------------------------------------------------------------


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.partition(":")[2].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def meta(opts: Options) -> dict[str, Any]:
    """Date, machine, versions, the command."""
    now = _dt.datetime.now(_dt.UTC)
    return {
        "date": now.strftime("%Y-%m-%d %H:%M UTC"),
        "cpu": _cpu_model(),
        "cores": os.cpu_count() or 0,
        "platform": f"{platform.system()} {platform.release()} {platform.machine()}",
        "python": f"{platform.python_implementation()} {platform.python_version()}",
        "pymb": pymb.__version__,
        "libmodbus": _native.LIBMODBUS_VERSION,
        "command": opts.command,
        "quick": opts.quick,
        "sections": list(opts.sections),
        "plan": opts.plan.__dict__,
        "section_seconds": {},  #: what each section run took, in the order run
        "quick_budget": {k: QUICK_BUDGET[k] for k in opts.sections if k in QUICK_BUDGET},
    }


def targets(result: dict[str, Any]) -> list[dict[str, Any]]:
    """The targets against what this run measured (None: not measured)."""
    out: list[dict[str, Any]] = []

    def add(what: str, target: str, value: float | None, unit: str, ok: bool | None) -> None:
        out.append({"what": what, "target": target, "measured": value, "unit": unit,
                    "met": ok})

    def row(rows: list[dict[str, Any]], name: str, **match: Any) -> dict[str, Any]:
        for r in rows:
            if r.get("name") == name and all(r.get(k) == v for k, v in match.items()):
                return r
        return {}

    sweep = result.get("sweep")
    if sweep:
        p = row(sweep["hub"]["rows"], "pymb")
        w, c = p.get("wall_x"), p.get("cpu_x")
        add("hub sweep wall time, pymb / C", "<= 1.10", w, "x", None if w is None else w <= 1.10)
        # The CPU goal is C's own: read_all(into=r) allocates nothing.
        add("hub sweep CPU time, pymb / C", "<= 1.00", c, "x", None if c is None else c <= 1.00)
        tele = row(sweep["telemetry"]["rows"], "pymb") if sweep.get("telemetry") else {}
        c = tele.get("cpu_x")
        add("CoolPro telemetry CPU time, pymb / C", "<= 1.20", c, "x",
            None if c is None else c <= 1.20)
    micro = result.get("micro")
    if micro:
        for r in micro["rows"]:
            add(f"{r['what']} from Python", f"<= {r['target_us']:g} us", r["pymb_us"], "us",
                r["pymb_us"] <= r["target_us"])
    maps = result.get("maps") or {}
    for section, mod in ((result.get("plan"), planbench), (maps, mapbench),
                         (maps.get("wire"), mapwire)):
        for t in mod.targets(section) if section else []:
            add(*t)
    wire = result.get("wire")
    if wire:
        for baud in (9600, 115200):
            r = row(wire["rows"], "pymb", baud=baud, workload="hub sweep")
            x = r.get("theory_x")
            add(f"hub sweep at emulated {baud}, / theoretical wire time", "<= 1.02", x, "x",
                None if x is None else x <= 1.02)
    scaling = result.get("scaling")
    if scaling:
        r = scaling["rows"][-1]
        add(f"{r['buses']} buses in parallel, sweeps/s / 1 bus", ">= 7.5", r["speedup"], "x",
            r["speedup"] >= 7.5)
    for key, mod in (("aio", aiobench), ("logger", logbench), ("gateway", gatebench),
                     ("serve", servebench)):
        for t in mod.targets(result[key]) if result.get(key) else []:
            add(*t)
    return out


def run(opts: Options) -> dict[str, Any]:
    """Run the chosen sections, timing each (``meta.section_seconds``, against
    :data:`~pymb.bench.options.QUICK_BUDGET` with ``--quick``); returns the
    result (JSON-able)."""
    result: dict[str, Any] = {"meta": meta(opts)}
    pymb_in = "pymb" in opts.only
    with tempfile.TemporaryDirectory(prefix="pymb-bench-") as tmp, \
            Children(fork=opts.quick) as children:
        lineup = Lineup(opts, children, tmp)
        result["contenders"] = [
            {"name": e.name, "label": e.contender.label, "version": e.version,
             "status": e.status, "reason": e.reason, "how": e.contender.how}
            for e in lineup.entries()]
        result["c_warnings"] = lineup.c_warnings
        c_in = "c" in opts.only
        steps: list[tuple[str, bool, Callable[[], Any]]] = [
            ("micro", pymb_in, lambda: run_micro(opts)),
            ("plan", pymb_in, lambda: planbench.run_section(opts.plan.micro_repeat, opts.say)),
            ("maps", pymb_in, lambda: {**mapbench.run_section(opts.plan.micro_repeat, opts.say),
                                       "wire": mapwire.run_section(opts, children)}),
            ("sweep", True, lambda: run_sweep(opts, lineup, children)),
            ("wire", pymb_in or c_in, lambda: run_wire(opts, lineup, children)),
            ("scaling", pymb_in, lambda: run_scaling(opts, children)),
            ("aio", pymb_in, lambda: aiobench.run_section(opts, children, lineup.ref,
                                                          _software_devices())),
            ("fleet", pymb_in, lambda: fleet.run_fleet(opts.quick, opts.say)),
            ("collect", pymb_in, lambda: collectbench.run_collect(opts.quick, opts.say)),
            ("logger", pymb_in, lambda: logbench.run_section(opts, children, hub_registers())),
            ("gateway", pymb_in, lambda: gatebench.run_section(opts, children, tmp)),
            ("soak", pymb_in, lambda: soak.run_section(60.0 if opts.quick else None, opts.say)),
            ("writes", pymb_in, lambda: writebench.run_writes(opts.quick, opts.say)),
            ("serve", pymb_in, lambda: servebench.run_section(opts, children)),
        ]
        took: dict[str, float] = result["meta"]["section_seconds"]
        for name, wanted, step in steps:
            if name in opts.sections and wanted:
                t0 = time.monotonic()
                result[name] = step()
                took[name] = time.monotonic() - t0
    # --quick is a smoke test: its figures are indicative and it judges no target.
    result["targets"] = [] if opts.quick else targets(result)
    return result
