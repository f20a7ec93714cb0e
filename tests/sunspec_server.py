"""A SunSpec device that is not pymb: pymodbus serving a register image that
pysunspec2 built (tests/sunspec_peer.py), for the SunSpec tests. Run as
``python tests/sunspec_server.py FILE``; FILE is JSON ``{"unit": 1, "base":
40000, "registers": [...]}`` (the holding registers from ``base`` on). It
prints ``READY <port>``, serves on 127.0.0.1 and then takes commands on
stdin, one JSON line each: ``{"after": N, "set": {"ADDRESS": [VALUE, ...],
...}}`` waits until N more requests have come (at most 60 s), then writes the
registers from each address at once (one write request of its own, function
16, to itself) and prints ``OK <requests so far>``. A read outside the image is answered with
exception 02.
"""

from __future__ import annotations

import asyncio
import json
import sys

from pymodbus.client import AsyncModbusTcpClient
from pymodbus.datastore import ModbusDeviceContext, ModbusServerContext, ModbusSparseDataBlock
from pymodbus.server import ModbusTcpServer
from pymodbus_server import free_port, serve_announced

REQUESTS = [0]


def count(sending: bool, packet: bytes) -> bytes:
    if not sending:
        REQUESTS[0] += 1
    return packet


async def commands(port: int, unit: int) -> None:
    loop = asyncio.get_running_loop()
    while True:
        line = await loop.run_in_executor(None, sys.stdin.readline)
        if not line:
            return
        cmd = json.loads(line)
        until = REQUESTS[0] + cmd.get("after", 0)
        for _ in range(3000):
            if REQUESTS[0] >= until:
                break
            await asyncio.sleep(0.02)
        writes = cmd.get("set", {})
        if writes:
            client = AsyncModbusTcpClient("127.0.0.1", port=port, timeout=10)
            await client.connect()
            for address, values in writes.items():
                reply = await client.write_registers(int(address), values, device_id=unit)
                assert not reply.isError(), reply
            client.close()
        print("OK", REQUESTS[0], flush=True)


async def main(path: str) -> None:
    with open(path, encoding="utf-8") as f:
        spec = json.load(f)
    base = spec["base"]
    # Sparse blocks are addressed as on the wire (no +1, unlike sequential ones).
    block = ModbusSparseDataBlock(  # type: ignore[no-untyped-call]
        {base + i: [v] for i, v in enumerate(spec["registers"])})
    device = ModbusDeviceContext(hr=block)
    port = free_port()
    server = ModbusTcpServer(ModbusServerContext(devices={spec["unit"]: device}, single=False),
                             address=("127.0.0.1", port), trace_packet=count)
    task = asyncio.create_task(commands(port, spec["unit"]))
    await serve_announced(server, port)
    task.cancel()


if __name__ == "__main__":
    asyncio.run(main(sys.argv[1]))
