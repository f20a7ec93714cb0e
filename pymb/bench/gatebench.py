"""The bench's ``gateway`` section: many Modbus TCP devices polled flat out
by one process, each poll stored in SQLite.

One simulator process serves N ports on 127.0.0.1 (``pymb simulate --tcp
127.0.0.1:0 --count N``), each port a TCP device with fixed values; each
design (:mod:`pymb.bench.gateworker`) runs in its own process, polls every
port flat out and stores each poll's registers as one SQLite row. Counted:
the worker's own CPU (every thread's, from getrusage: the simulator's CPU is
not the logger's), the values it stored per CPU-second, CPU per poll, RSS
and threads, over a steady window after a warm-up. Two workloads: a map of
10 f32 points (one request a poll) and the shipped ``eastron-sdm630`` map
(74 points, 9 requests a poll as the planner cuts them).
"""

from __future__ import annotations

import json
import os
import sys
from typing import Any

from pymb.bench.contenders import CONTENDERS, probe
from pymb.bench.gateworker import DESIGNS
from pymb.bench.options import Options
from pymb.bench.procs import Child, ChildError, Children
from pymb.bench.report import Table, fmt_time
from pymb.child import pymb_argv

__all__ = ["RSS_TARGET_MB", "TEN_POINTS", "VALUES_TARGET", "run_section", "tables",
           "targets"]

VALUES_TARGET = 1_000_000  #: values stored per CPU-second, SDM630 map
RSS_TARGET_MB = 60.0  #: at 300 devices
#: the 10-point device: ten f32 input registers, read in one request
TEN_POINTS = """schema = "pymb.map/1"

[device]
id = "ten-floats"
description = "Ten f32 values in input registers 0..19"
default_address = 1
table = "input"
order = "ABCD"
""" + "".join(f"""
[[point]]
name = "value_{i}"
address = {2 * i}
type = "f32"
example = {i}.5
""" for i in range(10))

LABELS = {"fanout": "pymb fan-out (1 thread, 1 request in flight)",
          "fanout-pipelined": "pymb fan-out, a poll's requests pipelined",
          "threads": "a thread per connection (pymb framing)",
          "pymodbus": "pymodbus AsyncModbusTcpClient"}


def _one(children: Children, design: str, map_arg: str, ports: str, db: str,
         warmup: float, seconds: float) -> dict[str, Any]:
    child = children.add(Child(f"gateway {design}", [
        sys.executable, "-m", "pymb.bench.gateworker", design, map_arg, "127.0.0.1", ports,
        db, "--warmup", str(warmup), "--seconds", str(seconds)], stdin=False))
    try:
        r: dict[str, Any] = json.loads(child.readline(90.0 + warmup + seconds))
    finally:
        children.stop(child)
    cpu = r["cpu_s"]
    r["values_per_cpu_s"] = r["samples"] * r["values_per_poll"] / cpu if cpu else None
    r["cpu_per_poll_us"] = cpu / r["samples"] * 1e6 if r["samples"] else None
    return r


def run_section(opts: Options, children: Children, tmp: str) -> dict[str, Any]:
    """Every workload x device count x design; the designs' rows."""
    counts = (10, 30) if opts.quick else (10, 100, 300)
    warmup, seconds = (0.5, 1.0) if opts.quick else (1.0, 3.0)
    ten = os.path.join(tmp, "ten-floats.toml")
    with open(ten, "w", encoding="utf-8") as f:
        f.write(TEN_POINTS)
    skip = probe(next(c for c in CONTENDERS if c.name == "pymodbus"))[0]
    rows: list[dict[str, Any]] = []
    for workload, map_arg, sim_args in (
            ("10 points", ten, ["--map", ten, "ten-floats:1,dynamic=0"]),
            ("SDM630", "eastron-sdm630", ["eastron-sdm630:1,dynamic=0"])):
        for n in counts:
            sim = children.add(Child(f"simulator x{n}", pymb_argv(
                "simulate", *sim_args, "--tcp", "127.0.0.1:0", "--count", str(n)),
                stdin=False))
            try:
                ports = sim.readline(60.0).strip().rpartition(":")[2]
                for design in DESIGNS:
                    row: dict[str, Any] = {"workload": workload, "devices": n,
                                           "design": design}
                    if design == "pymodbus" and skip:
                        row.update(status="skipped", reason=skip)
                    else:
                        db = os.path.join(tmp, f"gateway-{design}-{n}.db")
                        opts.say(f"gateway: {workload}, {n} devices, {design}")
                        try:
                            row.update(_one(children, design, map_arg, ports, db, warmup,
                                            seconds), status="ok")
                        except (ChildError, ValueError, KeyError) as e:
                            row.update(status="failed", reason=str(e)[:300])
                        for suffix in ("", "-wal", "-shm"):
                            if os.path.exists(db + suffix):
                                os.remove(db + suffix)
                    rows.append(row)
            finally:
                children.stop(sim)
    return {"warmup": warmup, "seconds": seconds, "rows": rows}


def _best(section: dict[str, Any], workload: str) -> dict[str, Any] | None:
    ok = [r for r in section["rows"] if r["workload"] == workload and r["status"] == "ok"
          and r["design"].startswith("fanout") and r["values_per_cpu_s"]]
    return max(ok, key=lambda r: r["values_per_cpu_s"], default=None)


def targets(section: dict[str, Any]) -> list[tuple[str, str, float | None, str, bool | None]]:
    """(what, goal, measured, unit, met): SDM630 values per CPU-second (the
    lowest of pymb's pipelined rows over the device counts), RSS at the most
    devices."""
    piped = [r for r in section["rows"] if r["workload"] == "SDM630" and r["status"] == "ok"
             and r["design"] == "fanout-pipelined"]
    low = min((r["values_per_cpu_s"] for r in piped), default=None)
    most = max((r["devices"] for r in section["rows"]), default=0)
    rss = [r["rss_kb"] / 1024 for r in section["rows"] if r["status"] == "ok"
           and r["devices"] == most and r["design"].startswith("fanout")]
    top = max(rss, default=None)
    return [("SDM630 values stored in SQLite per CPU-second of the poller, pipelined, "
             "every device count", f">= {VALUES_TARGET:,}", low, "values/s",
             None if low is None else low >= VALUES_TARGET),
            (f"poller RSS at {most} devices", f"< {RSS_TARGET_MB:g} MB", top, "MB",
             None if top is None else top < RSS_TARGET_MB)]


def tables(section: dict[str, Any]) -> list[Table]:
    """One table for the section."""
    rows = []
    for r in section["rows"]:
        if r["status"] != "ok":
            rows.append([r["workload"], str(r["devices"]), LABELS[r["design"]], r["status"],
                         "", "", "", "", ""])
            continue
        rows.append([r["workload"], str(r["devices"]), LABELS[r["design"]],
                     f"{r['values_per_cpu_s']:,.0f}", fmt_time(r["cpu_per_poll_us"]),
                     f"{r['samples'] / r['wall_s']:,.0f}", f"{r['rss_kb'] / 1024:.1f} MB",
                     str(r["threads"]), "yes" if r["checked"] else "NO"])
    return [Table(
        "Gateway: many Modbus TCP devices polled flat out, every poll stored in SQLite",
        f"one simulator process serves each device on its own port of 127.0.0.1; each "
        f"design in its own process; {section['seconds']:g} s measured after "
        f"{section['warmup']:g} s; values/CPU-s and CPU/poll count the poller's own CPU "
        "(all its threads), not the simulator's; polls/s is bounded by the simulator "
        "(a Python process) sharing the machine",
        ["workload", "devices", "design", "values / CPU-s", "CPU / poll", "polls/s", "RSS",
         "threads", "checked"], rows,
        [False, True, False, True, True, True, True, True, False],
        ["checked: the last stored sample decodes to what MapDevice reads from the device",
         "threads: the worker's two helpers (a stop watcher and a deadline timer) included"])]
