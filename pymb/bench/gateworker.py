"""One contender of the bench's ``gateway`` section, in its own process.

``python -m pymb.bench.gateworker DESIGN MAP HOST PORTS DB`` polls every port
(one TCP device each, the map's unit) flat out, stores each poll's registers
as one SQLite row (time, device, big-endian BLOB: the store's way) in
batches, and prints one JSON line: samples and values stored in the steady
window, this process's CPU seconds in it (every thread's), RSS, threads.

Designs: ``fanout`` (:class:`pymb.bench.fanout.TcpFanout`, one thread, one
epoll; a poll's requests one at a time: a poll of several requests read
reply by reply in Python, a poll of one request the C loop's),
``fanout-pipelined`` (the same, every request of a poll in flight at once:
every poll the C loop's, as ``pymb log``'s are), ``threads`` (a thread per
connection, blocking sockets, the same frames and checks), ``pymodbus``
(pymodbus's ``AsyncModbusTcpClient``, one per device, each polled by its own
task in one event loop).
"""

from __future__ import annotations

import argparse
import asyncio
import functools
import itertools
import json
import os
import resource
import socket
import sqlite3
import struct
import sys
import threading
import time
from collections.abc import Sequence
from typing import Any

from pymb.bench.cpuload import status_field
from pymb.bench.fanout import FanoutDevice, Sample, TcpFanout
from pymb.client import TcpClient
from pymb.devices.mapdevice import MapDevice
from pymb.maps import Decoder, Map, builtin, load
from pymb.maps.types import TABLE_FUNCTIONS
from pymb.sim.tcp import parse_ports

__all__ = ["DESIGNS", "SINK_ROWS", "GateSink", "main"]

DESIGNS = ("fanout", "fanout-pipelined", "threads", "pymodbus")


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


SINK_ROWS = 64  #: rows one INSERT carries at most (one statement step for them all)


@functools.lru_cache(maxsize=SINK_ROWS)
def _insert(n: int) -> str:
    return "INSERT INTO sample VALUES " + ", ".join(["(?, ?, ?)"] * n)


class GateSink:
    """The sink of every design: batches of samples into one SQLite table,
    one transaction a batch, :data:`SINK_ROWS` rows an INSERT (as ``pymb log``'s
    writer binds them); measures the steady window (``warmup`` s after the
    first batch, for ``seconds``) and sets :attr:`done` at its end."""

    def __init__(self, path: str, warmup: float, seconds: float) -> None:
        self.db = sqlite3.connect(path, isolation_level=None, check_same_thread=False)
        self.db.execute("PRAGMA journal_mode=WAL")
        self.db.execute("PRAGMA synchronous=NORMAL")
        self.db.execute("CREATE TABLE IF NOT EXISTS sample (t INTEGER NOT NULL, "
                        "device INTEGER NOT NULL, registers BLOB NOT NULL)")
        self.warmup, self.seconds = warmup, seconds
        self.stored = 0
        self.t0: float | None = None
        self.start: tuple[float, float, int] | None = None  # wall, cpu, stored
        self.result: dict[str, Any] = {}
        self.done = threading.Event()
        self.threads = 0

    def __call__(self, batch: list[Sample]) -> None:
        if self.done.is_set():
            return
        db, flat, n = self.db, list(itertools.chain.from_iterable(batch)), len(batch)
        db.execute("BEGIN")
        for i in range(0, n, SINK_ROWS):
            k = min(SINK_ROWS, n - i)
            db.execute(_insert(k), flat[3 * i:3 * (i + k)])
        db.execute("COMMIT")
        self.stored += len(batch)
        now = time.monotonic()
        if self.t0 is None:
            self.t0 = now
        self.threads = max(self.threads, status_field("self", "Threads"))
        if self.start is None and now >= self.t0 + self.warmup:
            self.start = (now, _cpu(), self.stored)
        elif self.start is not None and now >= self.start[0] + self.seconds:
            wall, cpu, stored = self.start
            self.result = {"samples": self.stored - stored, "cpu_s": _cpu() - cpu,
                           "wall_s": now - wall, "rss_kb": status_field("self", "VmRSS"),
                           "hwm_kb": status_field("self", "VmHWM"), "threads": self.threads}
            self.done.set()


def plan(m: Map, host: str, port: int, unit: int) -> tuple[tuple[str, int, int], ...]:
    """The map planner's requests for one poll of every point."""
    dev = MapDevice(TcpClient(host, port), m, unit)
    return tuple((r.table, r.address, r.count) for r in dev.plan())


def values_per_poll(m: Map, d: FanoutDevice) -> int:
    """Values one poll stores (each point's channels)."""
    return sum(Decoder(m, table=t, address=first).slots for t, first, _, _ in d.layout())


def _fanout(devices: Sequence[FanoutDevice], store: GateSink, pipeline: int) -> None:
    f = TcpFanout(devices, store, interval=0, timeout=2.0, pipeline=pipeline, flush=0.1)

    def stopper() -> None:
        store.done.wait()
        f.stop()

    threading.Thread(target=stopper, daemon=True).start()
    f.run()


_REQ = struct.Struct(">HHHBBHH")
_HEAD = struct.Struct(">HHHBBB")


def _thread(d: FanoutDevice, index: int, out: list[Sample], stop: threading.Event) -> None:
    layout = {t: (first, off) for t, first, _, off in d.layout()}
    steps = []
    for i, (t, a, n) in enumerate(d.requests):
        first, off = layout[t]
        steps.append((_REQ.pack(i + 1, 0, 6, d.unit, TABLE_FUNCTIONS[t], a, n),
                      _HEAD.pack(i + 1, 0, 3 + 2 * n, d.unit, TABLE_FUNCTIONS[t], 2 * n), 9 + 2 * n,
                      off + 2 * (a - first)))
    image = bytearray(d.image_bytes)
    with socket.create_connection((d.host, d.port), timeout=2.0) as s:
        s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        buf = bytearray(300)
        view = memoryview(buf)
        while not stop.is_set():
            t0 = time.time_ns()
            for frame, head, size, off in steps:
                s.sendall(frame)
                got = 0
                while got < size:
                    k = s.recv_into(view[got:size])
                    if not k:
                        return
                    got += k
                if view[:9] != head:
                    raise RuntimeError(f"device {index}: a reply out of step")
                image[off:off + size - 9] = view[9:size]
            out.append((t0, index, image[:]))


def _threads(devices: Sequence[FanoutDevice], store: GateSink) -> None:
    out: list[Sample] = []
    stop = store.done
    threads = [threading.Thread(target=_thread, args=(d, i, out, stop), daemon=True)
               for i, d in enumerate(devices)]
    for t in threads:
        t.start()
    while not stop.wait(0.1):
        batch, out[:] = out[:], []  # appends between the two are rare and only delay
        if batch:
            store(batch)
    for t in threads:
        t.join(5.0)


async def _pymodbus(devices: Sequence[FanoutDevice], store: GateSink) -> None:
    from pymodbus.client import AsyncModbusTcpClient

    out: list[Sample] = []

    async def poll(d: FanoutDevice, index: int) -> None:
        c = AsyncModbusTcpClient(d.host, port=d.port, timeout=2, retries=0)
        await c.connect()
        layout = {t: (first, off) for t, first, _, off in d.layout()}
        image = bytearray(d.image_bytes)
        try:
            while not store.done.is_set():
                t0 = time.time_ns()
                for table, address, count in d.requests:
                    read = (c.read_input_registers if table == "input"
                            else c.read_holding_registers)
                    rr = await read(address, count=count, device_id=d.unit)
                    first, off = layout[table]
                    at = off + 2 * (address - first)
                    image[at:at + 2 * count] = struct.pack(f">{count}H", *rr.registers)
                out.append((t0, index, image[:]))
        finally:
            c.close()

    async def flush() -> None:
        while not store.done.is_set():
            await asyncio.sleep(0.1)
            batch, out[:] = out[:], []
            if batch:
                store(batch)

    await asyncio.gather(flush(), *(poll(d, i) for i, d in enumerate(devices)))


def _check(m: Map, d: FanoutDevice, db: sqlite3.Connection) -> bool:
    """The last stored sample of device 0 decodes to what MapDevice reads
    (the simulator's values are fixed in the bench)."""
    row = db.execute("SELECT registers FROM sample WHERE device = 0 ORDER BY rowid DESC "
                     "LIMIT 1").fetchone()
    if row is None:
        return False
    got: dict[str, Any] = {}
    for table, first, count, off in d.layout():
        regs = list(struct.unpack_from(f">{count}H", row[0], off))
        got.update(Decoder(m, table=table, address=first).read(regs))
    with TcpClient(d.host, d.port, timeout=2.0) as c:
        want = MapDevice(c, m, d.unit).read()
    return all(got[k] == v or v != v for k, v in want.items())  # v != v: NaN


def main(argv: Sequence[str] | None = None) -> int:
    """Run one design; print its JSON line."""
    p = argparse.ArgumentParser(prog="python -m pymb.bench.gateworker")
    p.add_argument("design", choices=DESIGNS)
    p.add_argument("map", help="a shipped map's id or a map file")
    p.add_argument("host")
    p.add_argument("ports")
    p.add_argument("db")
    p.add_argument("--unit", type=int, default=1)
    p.add_argument("--warmup", type=float, default=1.0)
    p.add_argument("--seconds", type=float, default=3.0)
    a = p.parse_args(argv)
    m = load(a.map) if os.path.exists(a.map) else builtin(a.map)
    ports = parse_ports(a.ports)
    requests = plan(m, a.host, ports[0], a.unit)
    devices = [FanoutDevice(a.host, port, a.unit, requests) for port in ports]
    store = GateSink(a.db, a.warmup, a.seconds)
    deadline = threading.Timer(a.warmup + a.seconds + 60.0, os._exit, (3,))
    deadline.daemon = True
    deadline.start()
    if a.design == "fanout":
        _fanout(devices, store, 1)
    elif a.design == "fanout-pipelined":
        _fanout(devices, store, len(requests))
    elif a.design == "threads":
        _threads(devices, store)
    else:
        asyncio.run(_pymodbus(devices, store))
    r = dict(store.result)
    r.update(values_per_poll=values_per_poll(m, devices[0]), requests=len(requests),
             checked=_check(m, devices[0], store.db))
    print(json.dumps(r), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
