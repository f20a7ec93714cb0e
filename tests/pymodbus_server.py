"""A pymodbus server, an independent slave for the wire tests: run as
``python tests/pymodbus_server.py tcp|rtu-over-tcp``; it prints ``READY
<port>`` and serves units 1 and 17 on 127.0.0.1 until killed.

Holding registers 0..999 hold 7 * address (mod 65536), input registers
40000 + address, coils the parity of the address; device identification
(function 0x2B / 0x0E) answers the six objects in IDENTITY.
"""

from __future__ import annotations

import asyncio
import socket
import sys

from pymodbus import FramerType, ModbusDeviceIdentification
from pymodbus.datastore import (
    ModbusDeviceContext,
    ModbusSequentialDataBlock,
    ModbusServerContext,
)
from pymodbus.server import ModbusTcpServer

IDENTITY = {
    "VendorName": "pymb tests",
    "ProductCode": "PM-1",
    "MajorMinorRevision": "3.16",
    "VendorUrl": "https://example.invalid/pymb",
    "ProductName": "independent slave",
    "ModelName": "pymodbus server",
}


def device() -> ModbusDeviceContext:
    # pymodbus's sequential blocks are addressed from 1 for address 0.
    return ModbusDeviceContext(
        hr=ModbusSequentialDataBlock(1, [(7 * a) & 0xFFFF for a in range(1000)]),
        ir=ModbusSequentialDataBlock(1, [40000 + a for a in range(1000)]),
        co=ModbusSequentialDataBlock(1, [a % 2 for a in range(1000)]),
        di=ModbusSequentialDataBlock(1, [1 - a % 2 for a in range(1000)]),
    )


def free_port() -> int:
    """A loopback TCP port free a moment ago, for the server to bind."""
    probe = socket.socket()
    probe.bind(("127.0.0.1", 0))
    port: int = probe.getsockname()[1]
    probe.close()
    return port


async def serve_announced(server: ModbusTcpServer, port: int) -> None:
    """Serve until killed, printing ``READY <port>`` once ``port`` accepts connections."""
    task = asyncio.create_task(server.serve_forever())
    for _ in range(200):
        await asyncio.sleep(0.02)
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
            break
        except OSError:
            continue
    print("READY", port, flush=True)
    await task


async def main(mode: str) -> None:
    port = free_port()
    context = ModbusServerContext(devices={1: device(), 17: device()}, single=False)
    server = ModbusTcpServer(
        context,
        framer=FramerType.RTU if mode == "rtu-over-tcp" else FramerType.SOCKET,
        identity=ModbusDeviceIdentification(info_name=IDENTITY),
        address=("127.0.0.1", port),
    )
    await serve_announced(server, port)


if __name__ == "__main__":
    asyncio.run(main(sys.argv[1]))
