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

A full run adds two ``pymb log`` rows at the rate plants poll, not flat out:
100 SDM630 devices every second (its CPU per stored value), and the peers'
published scenario, 10 gateways of 10 devices of 1,000 contiguous f32 input
registers each (:data:`PEERS_POINTS`), every second (values per CPU-second).
"""

from __future__ import annotations

import json
import os
import sqlite3
import sys
import time
from importlib import resources
from typing import Any

from pymb.bench.contenders import CONTENDERS, probe
from pymb.bench.cpuload import process_cpu, status_field
from pymb.bench.gateworker import DESIGNS, SINK_ROWS
from pymb.bench.options import Options
from pymb.bench.procs import ChildError, Children
from pymb.bench.table import Table, fmt_time
from pymb.child import pymb_argv
from pymb.client import TcpClient
from pymb.devices.mapdevice import MapDevice
from pymb.devices.mapreading import MapReading
from pymb.errors import ModbusError
from pymb.maps import Map, load
from pymb.sim.tcp import parse_ports
from pymb.store import samples_after

__all__ = ["LOG_TARGET", "PEERS", "PEERS_POINTS", "PEERS_TARGET", "RATE_DEVICES",
           "RATE_TARGET_US", "RSS_TARGET_MB", "TEN_POINTS", "VALUES_TARGET", "run_section",
           "tables", "targets"]

VALUES_TARGET = 1_000_000  #: values stored per CPU-second, SDM630 map
RSS_TARGET_MB = 60.0  #: at 300 devices
LOG_TARGET = 2_500_000  #: pymb log's SDM630 values per CPU-second at 100 devices, pipelined
RATE_TARGET_US = 5.0  #: pymb log's CPU per stored value, 100 SDM630 devices every second
PEERS_TARGET = 3_000_000  #: pymb log's values per CPU-second in the peers' scenario
RATE_DEVICES = 100  #: SDM630 devices of the at-rate row
#: the peers' scenario: gateways (a TCP port each) x devices (unit ids) behind each
PEERS = (10, 10)
def _floats(device_id: str, description: str, count: int, name: str) -> str:
    """A map of ``count`` contiguous f32 input registers from 0, named ``name`` + index."""
    head = f"""schema = "pymb.map/1"

[device]
id = "{device_id}"
description = "{description}"
default_address = 1
table = "input"
order = "ABCD"
"""
    return head + "".join(f"""
[[point]]
name = "{name}{i}"
address = {2 * i}
type = "f32"
example = {i}.5
""" for i in range(count))


#: the peers' device: 1,000 contiguous f32 input registers (16 requests of 125 registers)
PEERS_POINTS = _floats("peers-1000", "1,000 contiguous f32 values in input registers 0..1999",
                       1000, "v")
#: the 10-point device: ten f32 input registers, read in one request
TEN_POINTS = _floats("ten-floats", "Ten f32 values in input registers 0..19", 10, "value_")

LABELS = {"fanout": "pymb fan-out (1 thread, 1 request in flight)",
          "fanout-pipelined": "pymb fan-out, a poll's requests pipelined",
          "threads": "a thread per connection (pymb framing)",
          "pymodbus": "pymodbus AsyncModbusTcpClient",
          "pymb-log": "pymb log (one loop, 1 request in flight)",
          "pymb-log-pipelined": "pymb log (one loop, a poll's requests pipelined)",
          "pymb-log-1s": "pymb log, every device every 1 s, pipelined"}
LOG_DESIGNS = ("pymb-log", "pymb-log-pipelined")
RATE_WORKLOADS = ("SDM630 at 1 s", "peers: 1,000 f32 at 1 s")  #: the full run's at-rate rows


def flat_map(text: str) -> str:
    """A map's text without its polling groups, under another id: every
    point in one poll, at the bus's interval (0: flat out)."""
    out, in_groups = [], False
    for line in text.splitlines():
        stripped = line.strip()
        if stripped.startswith("["):
            in_groups = stripped == "[groups]"
        if in_groups or stripped.startswith("group ="):
            continue
        if stripped.startswith("id ="):
            line = line.replace('"', '"flat-', 1)
        out.append(line)
    return "\n".join(out) + "\n"


def _proc(pid: int) -> tuple[float, int, int]:
    """(CPU seconds, RSS kB, threads) of a running process."""
    return process_cpu(pid), status_field(pid, "VmRSS"), status_field(pid, "Threads")


def _stored(db: str) -> tuple[int, int]:
    """(last sample id, devices with a sample) of the logger's database."""
    if not os.path.exists(db):
        return 0, 0
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=5.0)
    try:
        last, devices = con.execute(
            "SELECT coalesce(max(id), 0), count(DISTINCT device_id) FROM samples").fetchone()
        return int(last), int(devices)
    except sqlite3.OperationalError:  # no table yet
        return 0, 0
    finally:
        con.close()


def _last_decodes(db: str, m: Map, port: str) -> bool:
    """The last stored sample decodes to what MapDevice reads from its device
    (the first one; the bench's values are fixed)."""
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=5.0)
    try:
        row = con.execute("SELECT s.id FROM samples s JOIN devices d ON d.id = s.device_id "
                          "WHERE d.name = 'd0' ORDER BY s.id DESC LIMIT 1").fetchone()
    finally:
        con.close()
    if row is None:
        return False
    (got,) = samples_after(db, row[0] - 1, limit=1)
    if not isinstance(got.data, MapReading):
        return False
    with TcpClient("127.0.0.1", int(port), timeout=2.0) as c:
        want = MapDevice(c, m, 1).read()
    return all(got.data.values[k] == v or v != v for k, v in want.items())  # v != v: NaN


def _pymb_log(children: Children, ports: list[str], tmp: str, map_file: str,
              pipelined: bool, warmup: float, seconds: float, *, interval: float = 0.0,
              units: int = 1, commit: float | None = 0.25) -> dict[str, Any]:
    """``pymb log`` itself: a bus per port with the map's device at each of
    ``units`` unit ids (every point in one poll), every ``interval`` seconds
    (0: flat out), commits every ``commit`` seconds (None: pymb log's
    default); every bus in its one loop; its CPU from /proc, samples from the
    database's ids."""
    db = os.path.join(tmp, f"gateway-log-{len(ports)}.sqlite")
    cfg = os.path.join(tmp, f"gateway-log-{len(ports)}.toml")
    m = load(map_file)
    requests = len(m.plan())
    pipe = f"pipeline = {min(16, requests)}\n" if pipelined else ""
    every = "" if commit is None else f"commit_interval_s = {commit}\n"
    with open(cfg, "w", encoding="utf-8") as f:
        f.write(f'[output]\npath = "{db}"\n{every}' + "".join(
            f'\n[[bus]]\nname = "d{i}"\ntcp = "127.0.0.1:{p}"\ninterval = {interval}\n'
            f'timeout = 2\n{pipe}' + "".join(
                f'  [[bus.device]]\n  map = "{map_file}"\n  address = {u}\n'
                f'  name = "d{i}{"" if u == 1 else f"u{u}"}"\n' for u in range(1, units + 1))
            for i, p in enumerate(ports)))
    child = children.start("gateway pymb log", pymb_argv(
        "log", "--config", cfg, "--seconds", str(warmup + seconds + 150), "--quiet"),
        stdin=False)
    try:
        deadline = time.monotonic() + 120.0
        while _stored(db)[1] < len(ports) * units:  # the warm-up starts once all store
            if time.monotonic() > deadline or child.proc.poll() is not None:
                raise ChildError(f"pymb log did not store from every device within 120 s: "
                                 f"{child.stderr_tail()}")
            time.sleep(0.1)
        time.sleep(warmup)
        t0, (cpu0, _, _), (id0, _) = time.monotonic(), _proc(child.pid), _stored(db)
        time.sleep(seconds)
        # The window also lasts until a commit has landed in it: a short one (--quick) on
        # a loaded machine can fall between two commits. Samples and CPU cover one span.
        until = time.monotonic() + 5.0
        while _stored(db)[0] == id0 and time.monotonic() < until:
            time.sleep(0.02)
        t1, (cpu1, rss, threads), (id1, devices) = (time.monotonic(), _proc(child.pid),
                                                     _stored(db))
        if child.proc.poll() is not None:
            raise ChildError(f"pymb log ended before the window did: {child.stderr_tail()}")
        checked = devices == len(ports) * units and _last_decodes(db, m, ports[0])
    finally:
        children.stop(child)
        for suffix in ("", "-wal", "-shm"):
            if os.path.exists(db + suffix):
                os.remove(db + suffix)
    values = sum(p.channels for p in m.points.values() if p.access != "w")
    samples, cpu = id1 - id0, cpu1 - cpu0
    return {"samples": samples, "cpu_s": cpu, "wall_s": t1 - t0, "rss_kb": rss,
            "hwm_kb": rss, "threads": threads, "values_per_poll": values,
            "requests": requests, "checked": checked,
            "values_per_cpu_s": samples * values / cpu if cpu else None,
            "cpu_per_poll_us": cpu / samples * 1e6 if samples else None,
            "cpu_per_value_us": cpu / (samples * values) * 1e6 if samples else None}


def _one(children: Children, design: str, map_arg: str, ports: str, db: str,
         warmup: float, seconds: float) -> dict[str, Any]:
    child = children.start(f"gateway {design}", [
        sys.executable, "-m", "pymb.bench.gateworker", design, map_arg, "127.0.0.1", ports,
        db, "--warmup", str(warmup), "--seconds", str(seconds)], stdin=False)
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
    # --quick: the target's workload (SDM630) at 10 devices, short runs, to fit its budget
    counts = (10,) if opts.quick else (10, 100, 300)
    warmup, seconds = (0.1, 0.3) if opts.quick else (1.0, 3.0)
    ten = os.path.join(tmp, "ten-floats.toml")
    with open(ten, "w", encoding="utf-8") as f:
        f.write(TEN_POINTS)
    sdm = os.path.join(tmp, "flat-sdm630.toml")  # every point in one poll, flat out
    with open(sdm, "w", encoding="utf-8") as f:
        f.write(flat_map((resources.files("pymb.maps") / "builtin" / "eastron-sdm630.toml")
                         .read_text(encoding="utf-8")))
    skip = probe(next(c for c in CONTENDERS if c.name == "pymodbus"))[0]
    rows: list[dict[str, Any]] = []
    workloads = [("10 points", ten, ten, ["--map", ten, "ten-floats:1,dynamic=0"]),
                 ("SDM630", "eastron-sdm630", sdm, ["eastron-sdm630:1,dynamic=0"])]
    for workload, map_arg, log_map, sim_args in workloads[1:] if opts.quick else workloads:
        for n in counts:
            sim = children.start(f"simulator x{n}", pymb_argv(
                "simulate", *sim_args, "--tcp", "127.0.0.1:0", "--count", str(n)),
                stdin=False)
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
                for design in LOG_DESIGNS:
                    opts.say(f"gateway: {workload}, {n} devices, {design}")
                    row = {"workload": workload, "devices": n, "design": design}
                    try:
                        row.update(_pymb_log(children, [str(p) for p in parse_ports(ports)],
                                             tmp, log_map, design.endswith("pipelined"),
                                             warmup, seconds), status="ok")
                    except (ChildError, OSError, sqlite3.Error, ModbusError) as e:
                        row.update(status="failed", reason=str(e)[:300])
                    rows.append(row)
            finally:
                children.stop(sim)
    if not opts.quick:
        rows += _at_rate(opts, children, tmp, sdm)
    return {"warmup": warmup, "seconds": seconds, "rows": rows}


def _at_rate(opts: Options, children: Children, tmp: str, sdm: str) -> list[dict[str, Any]]:
    """pymb log polling every device every second (pipelined, its default
    commit interval): 100 SDM630 devices, then the peers' scenario."""
    peers = os.path.join(tmp, "peers-1000.toml")
    with open(peers, "w", encoding="utf-8") as f:
        f.write(PEERS_POINTS)
    gateways, behind = PEERS
    runs = [(RATE_WORKLOADS[0], sdm, RATE_DEVICES, 1, ["eastron-sdm630:1,dynamic=0"]),
            (RATE_WORKLOADS[1], peers, gateways, behind,
             ["--map", peers, *(f"peers-1000:{u},dynamic=0" for u in range(1, behind + 1))])]
    rows: list[dict[str, Any]] = []
    for workload, log_map, ports, units, sim_args in runs:
        opts.say(f"gateway: pymb log, {workload}, {ports * units} devices")
        row: dict[str, Any] = {"workload": workload, "devices": ports * units,
                               "design": "pymb-log-1s"}
        sim = children.start(f"simulator x{ports}", pymb_argv(
            "simulate", *sim_args, "--tcp", "127.0.0.1:0", "--count", str(ports)), stdin=False)
        try:
            got = sim.readline(60.0).strip().rpartition(":")[2]
            row.update(_pymb_log(children, [str(p) for p in parse_ports(got)], tmp, log_map,
                                 True, 2.0, 10.0, interval=1.0, units=units, commit=None),
                       status="ok")
        except (ChildError, OSError, sqlite3.Error, ModbusError) as e:
            row.update(status="failed", reason=str(e)[:300])
        finally:
            children.stop(sim)
        rows.append(row)
    return rows


def targets(section: dict[str, Any]) -> list[tuple[str, str, float | None, str, bool | None]]:
    """(what, goal, measured, unit, met): SDM630 values per CPU-second (the
    lowest of pymb's pipelined rows over the device counts: the fan-out's,
    then ``pymb log``'s), RSS at the most devices (pymb's rows); with rows
    for them, ``pymb log``'s values per CPU-second at 100 devices (issue
    30's goal), its CPU per value at 1 s and the peers' scenario's values
    per CPU-second."""
    piped = [r for r in section["rows"] if r["workload"] == "SDM630" and r["status"] == "ok"
             and r["design"] == "fanout-pipelined"]
    low = min((r["values_per_cpu_s"] or 0.0 for r in piped), default=None)
    most = max((r["devices"] for r in section["rows"]), default=0)
    rss = [r["rss_kb"] / 1024 for r in section["rows"] if r["status"] == "ok"
           and r["devices"] == most and (r["design"].startswith("fanout")
                                         or r["design"] in LOG_DESIGNS)]
    top = max(rss, default=None)
    logged = [r["values_per_cpu_s"] or 0.0 for r in section["rows"]
              if r["workload"] == "SDM630" and r["status"] == "ok"
              and r["design"] == "pymb-log-pipelined"]
    log_low = min(logged, default=None)
    out: list[tuple[str, str, float | None, str, bool | None]] = [
        ("SDM630 values stored in SQLite per CPU-second of the poller, pipelined, "
         "every device count", f">= {VALUES_TARGET:,}", low, "values/s",
         None if low is None else low >= VALUES_TARGET),
        ("... of pymb log itself, pipelined, every device count", f">= {VALUES_TARGET:,}",
         log_low, "values/s", None if log_low is None else log_low >= VALUES_TARGET),
        (f"poller RSS at {most} devices", f"< {RSS_TARGET_MB:g} MB", top, "MB",
         None if top is None else top < RSS_TARGET_MB)]
    at100 = [r["values_per_cpu_s"] or 0.0 for r in section["rows"]
             if r["workload"] == "SDM630" and r["status"] == "ok"
             and r["design"] == "pymb-log-pipelined" and r["devices"] == RATE_DEVICES]
    if at100:
        out.append((f"pymb log, SDM630 values per CPU-second at {RATE_DEVICES} devices, "
                    "pipelined, flat out", f">= {LOG_TARGET:,}", min(at100), "values/s",
                    min(at100) >= LOG_TARGET))
    for workload, what, goal, key, better in (
            (RATE_WORKLOADS[0], f"pymb log, CPU per stored value, {RATE_DEVICES} SDM630 "
             "devices every 1 s", RATE_TARGET_US, "cpu_per_value_us", False),
            (RATE_WORKLOADS[1], "pymb log, values per CPU-second, the peers' scenario "
             "(10 x 10 devices of 1,000 f32, every 1 s)", PEERS_TARGET, "values_per_cpu_s",
             True)):
        row = next((r for r in section["rows"] if r["workload"] == workload), None)
        if row is None:
            continue
        value = row.get(key) if row["status"] == "ok" else None
        out.append((what, f">= {goal:,.0f}" if better else f"<= {goal:g}", value,
                    "values/s" if better else "us",
                    None if value is None else (value >= goal if better else value <= goal)))
    return out


def tables(section: dict[str, Any]) -> list[Table]:
    """One table for the section."""
    rows = []
    for r in section["rows"]:
        if r["status"] != "ok":
            rows.append([r["workload"], str(r["devices"]), LABELS[r["design"]], r["status"],
                         "", "", "", "", ""])
            continue
        v = r["values_per_cpu_s"]
        rows.append([r["workload"], str(r["devices"]), LABELS[r["design"]],
                     "-" if v is None else f"{v:,.0f}", fmt_time(r["cpu_per_poll_us"]),
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
         "threads: the worker's two helpers (a stop watcher and a deadline timer) included",
         "pymb fan-out: the bench's bare loop, on pymb log's C master and (a poll's requests "
         "all in flight) its C loop, with none of the logger: no groups, re-plans, events or "
         "writer thread; every design but pymb log stores through one sink (a transaction a "
         f"batch, {SINK_ROWS} rows an INSERT)"])]
