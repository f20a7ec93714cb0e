"""The logger worker: ``python -m pymb.bench.logbench BAUD HUB_PORT COOLPRO_PORT DIR``.

Measures what ``pymb log`` costs on top of the bare read, pair by pair in
one process: each round first reads for a while with the bare facade call
(``SensorHub.read_all(into=...)`` or ``CoolPro.read_telemetry()``), then
runs the real :class:`~pymb.logger.Logger` (poller thread, queue, SQLite
sink on disk, batched commits) for the same while, and records the CPU
(``time.process_time``: every thread of this process) per sample of both.
Each device type logs into its own database in ``DIR``, appended to round
after round, so its bytes per sample are those of a long file.

Commands on stdin: ``run hub|coolpro ROUNDS SECONDS [on-change]`` answers
``ok`` and a JSON object; ``quit`` ends.
"""

from __future__ import annotations

import json
import os
import sqlite3
import statistics
import sys
import tempfile
import threading
import time
from array import array
from collections.abc import Callable, Sequence
from typing import Any

__all__ = ["BENCH_DEADBAND", "db_bytes", "main", "run_section", "targets"]

#: the on-change run's deadbands: about the sensors' noise (engineering units)
BENCH_DEADBAND = {"temperature_c": 0.5, "humidity_pct": 1.0, "pressure_temperature_c": 0.5,
                  "pressure_kpa": 2.0, "voltage_mv": 20.0, "rssi_dbm": 3.0,
                  "temperature2_c": 0.5}
BENCH_HEARTBEAT = 60.0

def db_bytes(path: str) -> dict[str, int]:
    """The database's size: file, WAL, and pages in use (file minus free pages)."""
    con = sqlite3.connect(path)
    try:
        page = con.execute("PRAGMA page_size").fetchone()[0]
        count = con.execute("PRAGMA page_count").fetchone()[0]
        free = con.execute("PRAGMA freelist_count").fetchone()[0]
        data = con.execute(
            "SELECT COALESCE(SUM(pgsize), 0) FROM dbstat WHERE name IN "
            "('samples', 'samples_time', 'hub_changes')").fetchone()[0]
    finally:
        con.close()
    wal = path + "-wal"
    return {"file": os.path.getsize(path),
            "wal": os.path.getsize(wal) if os.path.exists(wal) else 0,
            "used": int((count - free) * page), "data": int(data)}


def _count(path: str, table: str) -> int:
    """Rows in ``table`` of the database at ``path``."""
    con = sqlite3.connect(path)
    try:
        n: int = con.execute(f"SELECT COUNT(*) FROM {table}").fetchone()[0]
    finally:
        con.close()
    return n


def _bare_loop(read: Callable[[], Any], seconds: float) -> tuple[int, float]:
    n = 0
    c0 = time.process_time()
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        read()
        n += 1
    return n, time.process_time() - c0


def _steady(logger: Any, seconds: float, marks: list[tuple[float, int]]) -> None:
    """The logger's steady state: CPU and samples between 20 % and 95 % of the
    run (its start, first sweep planning and final checkpoint left out)."""
    t0 = time.monotonic()
    for share in (0.2, 0.95):
        time.sleep(max(0.0, t0 + share * seconds - time.monotonic()))
        marks.append((time.process_time(), logger.stats.samples))


def _span(port: str, baud: int, where: str, seconds: float, heartbeat: float,
          noise: bool) -> dict[str, Any]:
    """One long --on-change run of the hub: what it stores per sweep read."""
    from pymb.logger import BusConfig, DeviceConfig, LogConfig, Logger
    from pymb.store import OnChange

    path = os.path.join(where, f"span-{'noise' if noise else 'any'}.sqlite")
    bus = BusConfig("hub", port, None, baud, "N", 2.0, 0.0, [DeviceConfig("hub", 1)])
    cfg = LogConfig([bus], "sqlite", path)
    cfg.on_change = OnChange(heartbeat, dict(BENCH_DEADBAND) if noise else {})
    summary = Logger(cfg).run(seconds)
    size = db_bytes(path)
    rows = _count(path, "hub_changes")
    return {"seconds": seconds, "heartbeat": heartbeat, "deadband": noise,
            "samples": summary.samples, "channel_rows": rows, "bytes": size,
            "bytes_per_sample": size["data"] / max(1, summary.samples),
            "sweeps_per_s": summary.samples / summary.elapsed if summary.elapsed else 0.0}


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the logger worker."""
    args = list(sys.argv[1:] if argv is None else argv)
    if len(args) != 4:
        print("usage: python -m pymb.bench.logbench BAUD HUB_PORT COOLPRO_PORT DIR",
              file=sys.stderr)
        return 2
    from pymb import RtuClient
    from pymb.devices import COOLPRO, HUB, CoolPro, SensorHub
    from pymb.logger import BusConfig, DeviceConfig, LogConfig, Logger
    from pymb.store import OnChange

    baud, hub_port, cp_port, where = int(args[0]), args[1], args[2], args[3]
    ports = {"hub": hub_port, "coolpro": cp_port}
    addresses = {"hub": HUB.device.default_address, "coolpro": COOLPRO.device.default_address}
    try:
        clients = {k: RtuClient(p, baud, timeout=2.0) for k, p in ports.items()}
        for c in clients.values():
            c.connect()
        hub = SensorHub(clients["hub"], addresses["hub"])
        reading = hub.read_all()
        cp = CoolPro(clients["coolpro"], addresses["coolpro"])
        cp.read_telemetry()
    except Exception as e:
        print(f"err {type(e).__name__}: {e}".replace("\n", " "), flush=True)
        return 4
    bare: dict[str, Callable[[], Any]] = {
        "hub": lambda: hub.read_all(into=reading), "coolpro": cp.read_telemetry}
    print("ready", flush=True)
    try:
        for line in sys.stdin:
            cmd, *rest = line.split()
            if cmd == "quit":
                break
            if cmd == "span" and len(rest) == 5:
                print("ok " + json.dumps(_span(rest[0], int(rest[1]), where, float(rest[2]),
                                               float(rest[3]), rest[4] == "noise")), flush=True)
                continue
            if cmd != "run" or len(rest) not in (3, 4) or rest[0] not in ports:
                print(f"err bad command {line.strip()!r}", flush=True)
                continue
            kind, rounds, seconds = rest[0], int(rest[1]), float(rest[2])
            on_change = len(rest) == 4
            path = os.path.join(where, f"{kind}{'-onchange' if on_change else ''}.sqlite")
            pairs = []
            logged = 0
            try:
                for _ in range(rounds):
                    n_bare, cpu_bare = _bare_loop(bare[kind], seconds)
                    # The bare client lets go of the port while the logger has it.
                    clients[kind].close()
                    bus = BusConfig(kind, ports[kind], None, baud, "N", 2.0, 0.0,
                                    [DeviceConfig(kind, addresses[kind])])
                    cfg = LogConfig([bus], "sqlite", path)
                    if on_change:
                        cfg.on_change = OnChange(BENCH_HEARTBEAT, dict(BENCH_DEADBAND))
                    logger = Logger(cfg)
                    marks: list[tuple[float, int]] = []
                    timer = threading.Thread(target=_steady, args=(logger, seconds, marks))
                    timer.start()
                    summary = logger.run(seconds)
                    timer.join()
                    clients[kind].connect()
                    logged += summary.samples
                    (c0, n0), (c1, n1) = marks
                    pairs.append({"bare_n": n_bare, "bare_cpu": cpu_bare,
                                  "log_n": n1 - n0, "log_cpu": c1 - c0})
            except Exception as e:
                print(f"err {type(e).__name__}: {e}".replace("\n", " "), flush=True)
                continue
            size = db_bytes(path)
            stored = _count(path, "samples")
            ratios = [(p["log_cpu"] / p["log_n"]) / (p["bare_cpu"] / p["bare_n"])
                      for p in pairs if p["log_n"] and p["bare_n"]]
            print("ok " + json.dumps({
                "kind": kind, "on_change": on_change, "pairs": pairs,
                "bare_cpu_us": 1e6 * statistics.median(p["bare_cpu"] / p["bare_n"]
                                                       for p in pairs),
                "log_cpu_us": 1e6 * statistics.median(p["log_cpu"] / max(1, p["log_n"])
                                                      for p in pairs),
                "cpu_x": statistics.median(ratios) if ratios else None,
                "samples": logged, "stored_samples": stored, "bytes": size,
                "bytes_per_sample": size["data"] / logged if logged else None,
                "file_bytes_per_sample": (size["file"] + size["wal"]) / logged if logged
                else None,
            }), flush=True)
    finally:
        for c in clients.values():
            c.close()
    return 0


def run_section(opts: Any, children: Any, hub_registers: array[int]) -> dict[str, Any]:
    """The bench's ``logger`` section: the worker against two simulators
    (a hub, a CoolPro; 115200 set, no wire emulation), then the layouts."""
    from pymb.bench import layouts, wear
    from pymb.bench.procs import ChildError

    plan = opts.plan
    rounds, seconds = (1, 0.5) if opts.quick else (max(5, min(plan.rounds, 9)), 3.0)
    # --quick: the SD wear runs (processes of their own, mostly waiting out their
    # seconds) go on beside the rest of the section, once its CPU pairs are
    # measured (their short windows are the ones a busy machine empties), to fit
    # its budget
    wear_rows: list[dict[str, Any]] = []
    failed: list[BaseException] = []

    def wear_runs() -> None:
        try:
            wear_rows.extend(wear.run_wear(opts, children))
        except BaseException as e:  # handed to the section's thread
            failed.append(e)

    side = threading.Thread(target=wear_runs, name="pymb-bench-wear", daemon=True)
    opts.say("logger: starting the simulators")
    sims = children.sims([["hub:1,dynamic=0,baud=115200", "--seed", "0"],
                          ["coolpro:40,gap=0,baud=115200"]])
    with tempfile.TemporaryDirectory(prefix="pymb-bench-log-") as where:
        worker = children.start("logger worker", [
            sys.executable, "-m", "pymb.bench.logbench", "115200", sims[0].port, sims[1].port,
            where])
        line = worker.readline(60.0)
        if not line.startswith("ready"):
            raise ChildError(f"logger worker: {line}")
        runs = {}
        for kind, extra in (("hub", ""), ("coolpro", ""), ("hub", " on-change")):
            opts.say(f"logger: {kind}{extra}, {rounds} pairs of {seconds:g} s")
            runs[kind + extra.replace(" ", "_")] = json.loads(
                worker.ask(f"run {kind} {rounds} {seconds}{extra}", 120.0 + 4 * rounds * seconds))
        if opts.quick:
            side.start()
        span_s, heartbeat = (1.5, 0.5) if opts.quick else (60.0, 10.0)
        opts.say("logger: a hub on a line emulated at 115200, for --on-change")
        (wired,) = children.sims([["hub:1,dynamic=0", "--baud", "115200", "--seed", "0"]])
        spans = {}
        for noise in (False, True):
            what = "deadbands" if noise else "any change"
            opts.say(f"logger: hub --on-change ({what}), one run of {span_s:g} s")
            spans[what] = json.loads(worker.ask(
                f"span {wired.port} 115200 {span_s} {heartbeat} {'noise' if noise else 'any'}",
                120.0 + span_s))
        children.stop(wired)
        children.stop(worker)
        for s in sims:
            children.stop(s)
        n = 200 if opts.quick else 3000
        layout_rows = layouts.compare(hub_registers, where, n, opts.say)
        from pymb.bench import mapbytes
        map_rows = mapbytes.compare(where, 100 if opts.quick else 2000, opts.say,
                                    first_group_only=opts.quick)
    if opts.quick:
        side.join()
        if failed:
            raise failed[0]
    else:
        wear_runs()
        if failed:
            raise failed[0]
    full = runs["hub"]["bytes_per_sample"]
    for sp in spans.values():
        sp["saving"] = 1 - sp["bytes_per_sample"] / full if full else None
    return {
        "rounds": rounds, "seconds": seconds, "runs": runs,
        "deadband": BENCH_DEADBAND, "heartbeat": BENCH_HEARTBEAT, "spans": spans,
        "layouts": layout_rows, "layout_sweeps": n, "wear": wear_rows, "maps": map_rows,
    }


def targets(section: dict[str, Any]) -> list[tuple[str, str, float | None, str, bool | None]]:
    """The logger's targets against this run: (what, target, measured, unit, met)."""
    runs = section["runs"]
    hub, cp = runs["hub"], runs["coolpro"]
    out: list[tuple[str, str, float | None, str, bool | None]] = []
    for what, target, value, unit, limit in (
        ("bytes on disk per hub sweep (dbstat, index included)", "<= 2000",
         hub["bytes_per_sample"], "B", 2000.0),
        ("bytes on disk per CoolPro sample (dbstat, index included)", "<= 100",
         cp["bytes_per_sample"], "B", 100.0),
        ("pymb log CPU per hub sweep / bare read_all()", "<= 1.5", hub["cpu_x"], "x", 1.5),
        ("pymb log CPU per CoolPro sample / bare read_telemetry()", "<= 2", cp["cpu_x"], "x",
         2.0),
    ):
        out.append((what, target, value, unit, None if value is None else value <= limit))
    if section.get("wear"):
        from pymb.bench import wear
        out += wear.targets(section["wear"])
    return out


if __name__ == "__main__":
    sys.exit(main())
