"""A pymodbus server with only some registers: an independent slave for the
map tests. Run as ``python tests/pymodbus_sparse_server.py tcp|rtu-over-tcp
SPEC``; SPEC is JSON ``{"holding": {"ADDRESS": VALUE, ...}, "input": ...,
"coil": ..., "discrete": ...}``. It serves unit 5 on 127.0.0.1, prints
``READY <port>``, then one line ``REQ <monotonic seconds> <hex>`` for each
packet it receives, and answers a read that touches an address it lacks with
exception 02 (pymodbus's own sparse data blocks do that).
"""

from __future__ import annotations

import asyncio
import json
import sys
import time

from pymodbus import FramerType
from pymodbus.datastore import ModbusDeviceContext, ModbusServerContext, ModbusSparseDataBlock
from pymodbus.server import ModbusTcpServer
from pymodbus_server import free_port, serve_announced

UNIT = 5


def block(values: dict[str, int]) -> ModbusSparseDataBlock:
    # Sparse blocks are addressed as on the wire (no +1, unlike sequential ones).
    return ModbusSparseDataBlock(  # type: ignore[no-untyped-call]
        {int(a): [v] for a, v in values.items()} or {60000: [0]})


def trace(sending: bool, packet: bytes) -> bytes:
    if not sending:
        print("REQ", f"{time.monotonic():.6f}", packet.hex(), flush=True)
    return packet


async def main(mode: str, spec: dict[str, dict[str, int]]) -> None:
    port = free_port()
    device = ModbusDeviceContext(hr=block(spec.get("holding", {})),
                                 ir=block(spec.get("input", {})),
                                 co=block(spec.get("coil", {})),
                                 di=block(spec.get("discrete", {})))
    server = ModbusTcpServer(
        ModbusServerContext(devices={UNIT: device}, single=False),
        framer=FramerType.RTU if mode == "rtu-over-tcp" else FramerType.SOCKET,
        address=("127.0.0.1", port), trace_packet=trace)
    await serve_announced(server, port)


if __name__ == "__main__":
    asyncio.run(main(sys.argv[1], json.loads(sys.argv[2])))
