"""An asyncio contender's own process, for the bench's ``aio`` section.

``python -m pymb.bench.aioworker NAME PORT BAUD K_OFF K_VAL TIMEOUT`` speaks
:mod:`pymb.bench.worker`'s line protocol (``sweep N``, ``tele N``,
``verify``, ``tverify``, ``quit``) with one event loop: a batch of N
operations is one coroutine that awaits them one after another and times
each, so no loop start-up is in the figures. NAME: ``pymb-aio``
(:mod:`pymb.aio`) or ``pymodbus-async`` (pymodbus's ``AsyncModbusSerialClient``).

``python -m pymb.bench.aioworker lag NAME BAUD PORT...`` opens one client
and hub per port; ``run SECONDS`` polls every hub flat out (each in its own
task) while a 10 ms ticker measures the loop's lag, and answers ``ok`` and a
JSON object (the ticker's lateness, sweeps per hub, wall and CPU time). NAME
may also be ``blocking-in-loop``: pymb's blocking ``read_all`` called from
coroutines, the mistake the async clients exist to avoid (the control), or
``ticker-alone`` (no PORT): the ticker with nothing else to do.
"""

from __future__ import annotations

import asyncio
import json
import math
import sys
import time
from collections.abc import Awaitable, Callable, Sequence
from typing import Any

from pymb.bench import pure, worker
from pymb.bench.worker import (
    CP_ADDRESS,
    CP_COUNT,
    CP_FUNCTION,
    CP_SLAVE,
    HUB_SLAVE,
    SPANS,
    Canary,
    answer_commands,
    err_line,
)
from pymb.devices import CoolProTelemetry, HubReading

__all__ = ["CLIENTS", "LAG_STACKS", "Ticker", "main"]

Op = Callable[[], Awaitable[worker.Reading]]


class Ticker:
    """A 10 ms ticker on the running loop: how late each tick fires is the
    loop's lag, what a blocked loop shows first."""

    def __init__(self, period: float = 0.010) -> None:
        self.period = period
        self.late: list[float] = []  #: seconds late, one per tick
        self._task: asyncio.Task[None] | None = None

    async def _run(self) -> None:
        loop = asyncio.get_running_loop()
        due = loop.time() + self.period
        while True:
            await asyncio.sleep(max(0.0, due - loop.time()))
            now = loop.time()
            self.late.append(now - due)
            due = max(due + self.period, now)  # a long stall is one late tick

    def start(self) -> Ticker:
        """Start ticking on the running loop."""
        self._task = asyncio.get_running_loop().create_task(self._run())
        return self

    async def stop(self) -> None:
        """Stop ticking."""
        if self._task is not None:
            self._task.cancel()
            await asyncio.gather(self._task, return_exceptions=True)

    def quantile(self, q: float) -> float:
        """The ``q`` quantile (0..1) of the lateness, seconds."""
        late = sorted(self.late)
        if not late:
            return math.nan
        return late[min(len(late) - 1, math.ceil(q * len(late)) - 1)]

    def summary(self) -> dict[str, float]:
        """Ticks, and lateness in ms: median, p99, max."""
        return {"ticks": len(self.late), "p50_ms": 1e3 * self.quantile(0.5),
                "p99_ms": 1e3 * self.quantile(0.99), "max_ms": 1e3 * max(self.late, default=0)}


class PymbAio:
    """pymb.aio: ``await AsyncSensorHub.read_all(into=r)`` (one job on the
    line's worker per sweep) and ``await AsyncCoolPro.read_telemetry()``."""

    def __init__(self, port: str, baud: int, timeout: float) -> None:
        from pymb.aio import AsyncCoolPro, AsyncRtuClient, AsyncSensorHub

        self.client = AsyncRtuClient(port, baud, timeout=timeout)
        self.hub = AsyncSensorHub(self.client, HUB_SLAVE)
        self.coolpro = AsyncCoolPro(self.client, CP_SLAVE)
        self.reading: HubReading | None = None

    async def open(self) -> None:
        await self.client.connect()

    async def sweep(self) -> tuple[Sequence[int], Sequence[float]]:
        r = self.reading = await self.hub.read_all(into=self.reading)
        return r.registers, r.values

    async def telemetry(self) -> tuple[Sequence[int], CoolProTelemetry]:
        t = await self.coolpro.read_telemetry()  # as its user gets it (worker.PymbClient)
        return t.registers, t

    async def close(self) -> None:
        await self.client.close()


class PymodbusAsync:
    """pymodbus's ``AsyncModbusSerialClient`` (RTU framer), its defaults
    but for the timeout: six awaited reads per sweep and the pure-Python
    decode, all in the event loop (as its users run it)."""

    def __init__(self, port: str, baud: int, timeout: float) -> None:
        self.args = port, baud, timeout
        self.client: Any = None

    async def open(self) -> None:
        from pymodbus.client import AsyncModbusSerialClient
        from pymodbus.framer import FramerType

        port, baud, timeout = self.args  # made in the running loop, which it keeps
        self.client = AsyncModbusSerialClient(port, framer=FramerType.RTU, baudrate=baud,
                                              timeout=timeout)
        if not await self.client.connect():
            raise RuntimeError(f"pymodbus cannot open {port}")

    async def read(self, slave: int, function: int, address: int,
                   count: int) -> Sequence[int]:
        c = self.client
        if function == 0x04:
            rr = await c.read_input_registers(address, count=count, device_id=slave)
        else:
            rr = await c.read_holding_registers(address, count=count, device_id=slave)
        if rr.isError():
            raise RuntimeError(f"pymodbus: {rr}")
        regs: Sequence[int] = rr.registers
        return regs

    async def sweep(self) -> tuple[Sequence[int], Sequence[float]]:
        raw: list[int] = []
        for address, count in SPANS:
            raw += await self.read(HUB_SLAVE, 0x03, address, count)
        return raw, pure.decode_hub(raw)

    async def telemetry(self) -> tuple[Sequence[int], Sequence[float]]:
        raw = await self.read(CP_SLAVE, CP_FUNCTION, CP_ADDRESS, CP_COUNT)
        return raw, pure.decode_telemetry(raw)

    async def close(self) -> None:
        if self.client is not None:
            self.client.close()


class BlockingInLoop:
    """pymb's blocking ``SensorHub.read_all`` called from a coroutine: the
    loop stands still for every sweep (the control of the lag table)."""

    def __init__(self, port: str, baud: int, timeout: float) -> None:
        from pymb import RtuClient
        from pymb.devices import SensorHub

        self.client = RtuClient(port, baud, timeout=timeout)
        self.hub = SensorHub(self.client, HUB_SLAVE)

    async def open(self) -> None:
        self.client.connect()

    async def sweep(self) -> tuple[Sequence[int], Sequence[float]]:
        r = self.hub.read_all()
        await asyncio.sleep(0)  # the loop's turn between sweeps, no more
        return r.registers, r.values

    async def close(self) -> None:
        self.client.close()


#: contender name -> client class (one line, one hub and one CoolPro)
CLIENTS: dict[str, Callable[[str, int, float], Any]] = {
    "pymb-aio": PymbAio,
    "pymodbus-async": PymodbusAsync,
}
#: the stacks the lag run can poll with
LAG_STACKS: dict[str, Callable[[str, int, float], Any]] = {
    **CLIENTS, "blocking-in-loop": BlockingInLoop,
}


async def _batch(op: Op, n: int, check: worker.Check) -> str:
    walls = []
    clock = time.perf_counter_ns
    c0 = time.process_time_ns()  # every thread of the process: the worker's too
    for _ in range(n):
        t = clock()
        check(await op())
        walls.append(clock() - t)
    cpu = time.process_time_ns() - c0
    return f"ok {cpu} " + " ".join(map(str, walls))


def serve(loop: asyncio.AbstractEventLoop, client: Any, canary: Canary, lines: Any,
          out: Any) -> None:
    """Answer :mod:`pymb.bench.worker`'s commands until ``quit`` or EOF."""
    worker.serve(client, canary, lines, out,
                 batch=lambda op, n, check: loop.run_until_complete(_batch(op, n, check)),
                 call=lambda op: loop.run_until_complete(op()))


async def lag_run(clients: Sequence[Any], seconds: float) -> dict[str, Any]:
    """Poll every client's hub flat out for ``seconds`` under a 10 ms ticker."""
    counts = [0] * len(clients)
    loop = asyncio.get_running_loop()

    async def poll(i: int) -> None:
        end = loop.time() + seconds
        while loop.time() < end:
            await clients[i].sweep()
            counts[i] += 1

    ticker = Ticker().start()
    t0, c0 = time.perf_counter(), time.process_time()
    if not clients:  # the ticker alone: the machine's own lag
        await asyncio.sleep(seconds)
    await asyncio.gather(*(poll(i) for i in range(len(clients))))
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    await ticker.stop()
    return {**ticker.summary(), "sweeps": counts, "wall": wall, "cpu": cpu}


async def _warm(clients: Sequence[Any]) -> None:
    """Open every client, then sweep each once, side by side."""
    await asyncio.gather(*(c.open() for c in clients))
    await asyncio.gather(*(c.sweep() for c in clients))


def lag_main(args: Sequence[str]) -> int:
    """``lag NAME BAUD PORT...``: answer ``run SECONDS`` until ``quit``."""
    name, baud, ports = args[0], int(args[1]), args[2:]
    loop = asyncio.new_event_loop()
    clients = [] if name == "ticker-alone" else [LAG_STACKS[name](p, baud, 2.0) for p in ports]
    try:
        try:
            # opened and warmed side by side (the blocking stack's one by one)
            loop.run_until_complete(_warm(clients))
        except Exception as e:
            print(err_line(e), flush=True)
            return 4

        def answer(_cmd: str, rest: list[str], _line: str) -> str:
            try:
                return "ok " + json.dumps(loop.run_until_complete(lag_run(clients, float(rest[0]))))
            except Exception as e:
                return err_line(e)

        answer_commands(sys.stdin, answer)
    finally:
        for c in clients:
            loop.run_until_complete(c.close())
        loop.close()
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the worker process."""
    args = list(sys.argv[1:] if argv is None else argv)
    if len(args) >= 3 and args[0] == "lag" and (args[1] in LAG_STACKS
                                                 or args[1] == "ticker-alone"):
        return lag_main(args[1:])
    if len(args) != 6 or args[0] not in CLIENTS:
        print(f"usage: python -m pymb.bench.aioworker {{{','.join(CLIENTS)}}} PORT BAUD "
              "K_OFF K_VAL TIMEOUT\n       python -m pymb.bench.aioworker lag "
              f"{{{','.join(LAG_STACKS)},ticker-alone}} BAUD PORT...", file=sys.stderr)
        return 2
    name, port, baud, k_off, k_val, timeout = args
    loop = asyncio.new_event_loop()
    try:
        client = CLIENTS[name](port, int(baud), float(timeout))
        loop.run_until_complete(client.open())
    except Exception as e:
        print(f"err cannot open {port} with {name}: {type(e).__name__}: {e}".replace("\n", " "),
              flush=True)
        return 4
    print(f"ready {name}", flush=True)
    try:
        serve(loop, client, Canary(int(k_off), int(k_val)), sys.stdin, sys.stdout)
    finally:
        loop.run_until_complete(client.close())
        loop.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
