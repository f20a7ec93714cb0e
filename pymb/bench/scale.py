"""The scaling worker: ``python -m pymb.bench.scale BAUD PORT...``.

One :class:`~pymb.RtuClient` and :class:`~pymb.devices.SensorHub` per bus,
all opened at start and warmed by one sweep each (side by side). ``run K SECONDS`` sweeps
the first K buses in K threads (one per bus) for SECONDS and answers ``ok``
with a JSON object: sweeps per bus, each thread's span, the wall time and
this process's CPU (``time.process_time``, every thread). A sweep releases
the GIL for its whole C call, so the threads overlap on the wire.
"""

from __future__ import annotations

import json
import sys
import threading
import time
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any

from pymb.bench.worker import answer_commands, err_line

__all__ = ["main", "run_threads"]


def run_threads(hubs: Sequence[Any], seconds: float) -> dict[str, Any]:
    """Sweep every hub in its own thread for ``seconds``; the counts and times."""
    n = len(hubs)
    counts = [0] * n
    spans = [0.0] * n
    errors: list[str] = []
    start = threading.Barrier(n + 1)
    t0 = 0.0

    def loop(i: int) -> None:
        hub = hubs[i]
        start.wait()
        begin = time.perf_counter()
        deadline = t0 + seconds
        done = 0
        try:
            while time.perf_counter() < deadline:
                hub.read_all()
                done += 1
        except Exception as e:  # reported, the parent marks the run failed
            errors.append(f"bus {i + 1}: {type(e).__name__}: {e}")
        counts[i] = done
        spans[i] = time.perf_counter() - begin

    threads = [threading.Thread(target=loop, args=(i,), daemon=True) for i in range(n)]
    for t in threads:
        t.start()
    t0 = time.perf_counter()
    c0 = time.process_time()
    start.wait()
    for t in threads:
        t.join()
    wall = time.perf_counter() - t0
    cpu = time.process_time() - c0
    return {"buses": n, "sweeps": counts, "spans": spans, "wall": wall, "cpu": cpu,
            "errors": errors}


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the scaling worker."""
    args = list(sys.argv[1:] if argv is None else argv)
    if len(args) < 2:
        print("usage: python -m pymb.bench.scale BAUD PORT...", file=sys.stderr)
        return 2
    from pymb import RtuClient
    from pymb.devices import HUB, SensorHub

    baud, ports = int(args[0]), args[1:]
    clients = []
    try:
        try:
            for p in ports:
                c = RtuClient(p, baud, timeout=2.0)
                c.connect()
                clients.append(c)
            hubs = [SensorHub(c, HUB.device.default_address) for c in clients]
            # the warming sweeps side by side (each releases the GIL on the wire)
            with ThreadPoolExecutor(len(hubs)) as pool:
                list(pool.map(lambda h: h.read_all(), hubs))
        except Exception as e:
            print(err_line(e), flush=True)
            return 4

        def answer(cmd: str, rest: list[str], line: str) -> str:
            if cmd != "run" or len(rest) != 2 or not 1 <= int(rest[0]) <= len(hubs):
                return f"err bad command {line.strip()!r}"
            result = run_threads(hubs[:int(rest[0])], float(rest[1]))
            if result["errors"]:
                return "err " + "; ".join(result["errors"]).replace("\n", " ")
            return "ok " + json.dumps(result)

        answer_commands(sys.stdin, answer)
    finally:
        for c in clients:
            c.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
