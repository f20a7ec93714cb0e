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
import time
from collections.abc import Callable, Sequence
from typing import Any

__all__ = ["db_bytes", "main"]


def db_bytes(path: str) -> dict[str, int]:
    """The database's size: file, WAL, and pages in use (file minus free pages)."""
    con = sqlite3.connect(path)
    try:
        page = con.execute("PRAGMA page_size").fetchone()[0]
        count = con.execute("PRAGMA page_count").fetchone()[0]
        free = con.execute("PRAGMA freelist_count").fetchone()[0]
    finally:
        con.close()
    wal = path + "-wal"
    return {"file": os.path.getsize(path),
            "wal": os.path.getsize(wal) if os.path.exists(wal) else 0,
            "used": int((count - free) * page)}


def _bare_loop(read: Callable[[], Any], seconds: float) -> tuple[int, float]:
    n = 0
    c0 = time.process_time()
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        read()
        n += 1
    return n, time.process_time() - c0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the logger worker."""
    args = list(sys.argv[1:] if argv is None else argv)
    if len(args) != 4:
        print("usage: python -m pymb.bench.logbench BAUD HUB_PORT COOLPRO_PORT DIR",
              file=sys.stderr)
        return 2
    from pymb import RtuClient
    from pymb.devices import HUB, CoolPro, SensorHub
    from pymb.devices.maps import COOLPRO
    from pymb.logger import BusConfig, DeviceConfig, LogConfig, Logger

    baud, hub_port, cp_port, where = int(args[0]), args[1], args[2], args[3]
    ports = {"hub": hub_port, "coolpro": cp_port}
    addresses = {"hub": HUB.default_address, "coolpro": COOLPRO.default_address}
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
                        cfg.on_change = True  # type: ignore[attr-defined]
                    c0 = time.process_time()
                    summary = Logger(cfg).run(seconds)
                    cpu_log = time.process_time() - c0
                    clients[kind].connect()
                    logged += summary.samples
                    pairs.append({"bare_n": n_bare, "bare_cpu": cpu_bare,
                                  "log_n": summary.samples, "log_cpu": cpu_log})
            except Exception as e:
                print(f"err {type(e).__name__}: {e}".replace("\n", " "), flush=True)
                continue
            size = db_bytes(path)
            con = sqlite3.connect(path)
            try:
                stored = con.execute("SELECT COUNT(*) FROM samples").fetchone()[0]
            finally:
                con.close()
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
                "bytes_per_sample": size["used"] / logged if logged else None,
            }), flush=True)
    finally:
        for c in clients.values():
            c.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
