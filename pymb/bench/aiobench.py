"""The bench's ``aio`` section: :mod:`pymb.aio` side by side with pymb's
blocking calls and pymodbus's async client.

Per call: a hub sweep and a CoolPro telemetry read, each contender in its
own process (:mod:`pymb.bench.worker` for the blocking calls,
:mod:`pymb.bench.aioworker` for the async ones) against its own simulator
process over a pty, the software setup of the ``sweep`` section (115200 8N1,
no wire emulation); interleaved rounds, medians, ratios to the blocking
calls paired per round.

Loop lag: 8 hubs, each on its own simulator process, polled flat out (the
next sweep as soon as the last one ends) by one process's event loop while
a 10 ms ticker measures how late the loop runs it; once with the simulators
emulating 115200 baud (polling as fast as the wire allows) and once without
emulation (as fast as the CPUs allow: the two cores are then saturated by
the simulators, and the ticker waits for a CPU too). The stacks: pymb.aio,
pymodbus's async client, pymb's blocking calls made from coroutines (the
control: what the loop suffers without a worker thread), and the floor: the
ticker alone in an idle process while another process polls the same hubs
with blocking calls in threads (the lag the machine gives any process).
"""

from __future__ import annotations

import json
import statistics
import sys
import threading
from collections.abc import Sequence
from typing import Any

from pymb.bench.contenders import Contender, probe
from pymb.bench.options import Options
from pymb.bench.procs import Child, ChildError, Children
from pymb.bench.race import RaceEntry, Reference, _stop_all, race, summary, verify
from pymb.devices import HUB

__all__ = ["CONTENDERS", "LAG_TARGET_MS", "run_section", "targets"]

BAUD = 115200
HUBS = 8
LAG_TARGET_MS = 5.0  #: the event loop's p99 lag, 8 pymb.aio hubs at emulated 115200
_TIMEOUT = 2.0

CONTENDERS: tuple[Contender, ...] = (
    Contender("pymb", "pymb (blocking)", (), "pymb",
              "SensorHub.read_all(into=r) / CoolPro.read_telemetry(), called directly"),
    Contender("pymb-aio", "pymb.aio", (), "pymb",
              "await AsyncSensorHub.read_all(into=r) / AsyncCoolPro.read_telemetry(): "
              "one job on the line's worker thread per call"),
    Contender("pymodbus-async", "pymodbus async", ("pymodbus", "serial"), "pymodbus",
              "AsyncModbusSerialClient (RTU): 6 awaited read_holding_registers + Python "
              "decode, in the event loop"),
)
#: the lag run's stacks: (aioworker name, label)
LAG_STACKS = (("pymb-aio", "pymb.aio"), ("pymodbus-async", "pymodbus async"),
              ("blocking-in-loop", "pymb blocking, called in the loop"),
              ("ticker-alone", "the ticker alone (hubs polled by another process)"))


def _start(e: RaceEntry, port: str, ref: Reference, children: Children) -> None:
    module = "pymb.bench.worker" if e.name == "pymb" else "pymb.bench.aioworker"
    argv = [sys.executable, "-m", module, e.name, port, str(BAUD), str(ref.k_off),
            str(ref.k_val), str(_TIMEOUT)]
    e.start(argv, children)


def _per_call(opts: Options, children: Children, ref: Reference,
              devices: Sequence[str]) -> dict[str, Any]:
    plan = opts.plan
    entries = []
    for c in CONTENDERS:
        reason, version = probe(c)
        e = RaceEntry(c, version=version)
        if reason:
            e.status, e.reason = "skipped", reason
        entries.append(e)
    runnable = [e for e in entries if e.status == "ok"]
    opts.say(f"aio: starting {len(runnable)} simulators and contenders")
    sims = children.sims([[*devices, "--seed", "0"] for _ in runnable])
    for e, sim in zip(runnable, sims, strict=True):
        _start(e, sim.port, ref, children)
        if e.status == "ok":
            verify(e, ref, children, telemetry=True)
    rounds = max(2, plan.rounds // 2)
    race(entries, "hub", "sweep", rounds, plan.sweeps, plan.warm_sweeps, children, opts,
         "aio: hub sweep")
    race(entries, "telemetry", "tele", rounds, plan.reads, plan.warm_reads, children, opts,
         "aio: CoolPro telemetry")
    _stop_all(entries, sims, children)
    return {"baud": BAUD, "rounds": rounds, "sweeps": plan.sweeps, "reads": plan.reads,
            "hub": summary(entries, "hub", plan.sweeps, baseline="pymb"),
            "telemetry": summary(entries, "telemetry", plan.reads, baseline="pymb")}


def _started(child: Child) -> Child:
    ready = child.readline(60.0)
    if not ready.startswith("ready"):
        raise ChildError(ready)
    return child


def _ask_into(child: Child, command: str, timeout: float, box: dict[str, str]) -> None:
    box["answer"] = child.ask(command, timeout)


def _floor_runs(children: Children, ports: Sequence[str], seconds: float,
                repeats: int) -> list[dict[str, Any]]:
    """The ticker alone in a process of its own, while another process (the
    scaling worker: one thread per bus, blocking calls) polls the same hubs
    flat out: the lag the machine itself gives a waiting process."""
    scale = children.start("lag load", [sys.executable, "-m", "pymb.bench.scale",
                                            str(BAUD), *ports])
    ticker = children.start("lag ticker-alone", [
        sys.executable, "-m", "pymb.bench.aioworker", "lag", "ticker-alone", str(BAUD)])
    try:
        _started(scale)
        _started(ticker)
        runs = []
        for _ in range(repeats):
            load: dict[str, str] = {}
            t = threading.Thread(target=_ask_into, args=(
                scale, f"run {HUBS} {seconds + 0.5}", 60.0 + seconds, load))
            t.start()
            try:
                run = json.loads(ticker.ask(f"run {seconds}", 60.0 + seconds))
            finally:
                t.join()
            if "answer" not in load:
                raise ChildError("the load process did not answer")
            busy = json.loads(load["answer"])
            runs.append({**run, "sweeps": busy["sweeps"], "wall": busy["wall"],
                         "cpu": run["cpu"]})
        return runs
    finally:
        children.stop(ticker)
        children.stop(scale)


def _lag(opts: Options, children: Children, emulate: bool, seconds: float,
         repeats: int) -> list[dict[str, Any]]:
    spec = f"hub:{HUB.device.default_address},dynamic=0"
    args = [spec, "--baud", str(BAUD)] if emulate else [f"{spec},baud={BAUD}"]
    line = f"emulated {BAUD}" if emulate else "no emulation"
    sims = children.sims([[*args, "--seed", "0"] for _ in range(HUBS)])
    ports = [s.port for s in sims]
    rows = []
    for name, label in LAG_STACKS:
        row: dict[str, Any] = {"stack": name, "label": label, "line": line, "hubs": HUBS}
        reason = probe(CONTENDERS[2])[0] if name == "pymodbus-async" else None
        if reason:
            rows.append({**row, "status": "skipped", "reason": reason})
            continue
        opts.say(f"aio: loop lag, {label}, {HUBS} hubs, {line}")
        try:
            if name == "ticker-alone":
                runs = _floor_runs(children, ports, seconds, repeats)
            else:
                worker = children.start(f"lag {name}", [
                    sys.executable, "-m", "pymb.bench.aioworker", "lag", name, str(BAUD),
                    *ports])
                try:
                    _started(worker)
                    runs = [json.loads(worker.ask(f"run {seconds}", 60.0 + seconds))
                            for _ in range(repeats)]
                finally:
                    children.stop(worker)
        except (ChildError, ValueError) as err:
            rows.append({**row, "status": "failed", "reason": str(err)})
            continue
        rows.append({**row, "status": "ok", "runs": runs,
                     "p50_ms": statistics.median(r["p50_ms"] for r in runs),
                     "p99_ms": statistics.median(r["p99_ms"] for r in runs),
                     "max_ms": max(r["max_ms"] for r in runs),
                     "sweeps_per_s": statistics.median(sum(r["sweeps"]) / r["wall"]
                                                       for r in runs),
                     "cpu_pct": 100 * statistics.median(r["cpu"] / r["wall"] for r in runs)})
    for s in sims:
        children.stop(s)
    return rows


def run_section(opts: Options, children: Children, ref: Reference,
                devices: Sequence[str]) -> dict[str, Any]:
    """Both parts; ``ref`` checks the contenders' sweeps, ``devices`` are
    the software setup's simulated devices."""
    seconds, repeats = (0.5, 1) if opts.quick else (3.0, 3)
    per_call = _per_call(opts, children, ref, devices)
    # --quick: the lag on the emulated line only (the target's), to fit its budget
    lag = _lag(opts, children, True, seconds, repeats) + (
        [] if opts.quick else _lag(opts, children, False, seconds, repeats))
    return {**per_call, "lag": {"seconds": seconds, "repeats": repeats, "period_ms": 10.0,
                                "rows": lag}}


def targets(section: dict[str, Any]) -> list[tuple[str, str, float | None, str, bool | None]]:
    """This section's target: (what, goal, measured, unit, met)."""
    row = next((r for r in section["lag"]["rows"] if r["stack"] == "pymb-aio"
                and r["line"].startswith("emulated") and r["status"] == "ok"), None)
    p99 = None if row is None else row["p99_ms"]
    return [(f"event loop lag p99, {HUBS} pymb.aio hubs polled flat out (emulated {BAUD})",
             f"<= {LAG_TARGET_MS:g} ms", None if p99 is None else p99 * 1e3, "us",
             None if p99 is None else p99 <= LAG_TARGET_MS)]
