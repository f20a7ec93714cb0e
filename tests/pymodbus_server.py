"""A pymodbus server, an independent slave for the wire tests: run as
``python tests/pymodbus_server.py tcp|rtu-over-tcp|udp|ascii``, or ``tls DIR``
for Modbus/TCP Security with ``DIR``'s ``server.pem``/``server.key``, client
certificates required and signed by ``DIR/ca.pem``; it prints ``READY
<port>`` (``ascii``: ``READY <pty path>``) and serves units 1 and 17 on
127.0.0.1 (``ascii``: Modbus ASCII at 19200 baud 8N1 on a pseudo-terminal)
until killed.

``ascii``: pymodbus's serial server opens one pseudo-terminal, the client
another, and this process copies bytes between their two master ends (a
null-modem cable, as socat would make one).

Holding registers 0..999 hold 7 * address (mod 65536), input registers
40000 + address, coils the parity of the address; device identification
(function 0x2B / 0x0E) answers the six objects in IDENTITY.
"""

from __future__ import annotations

import asyncio
import os
import select
import socket
import ssl
import sys
import threading
import tty
from pathlib import Path

from pymodbus import FramerType, ModbusDeviceIdentification
from pymodbus.datastore import (
    ModbusDeviceContext,
    ModbusSequentialDataBlock,
    ModbusServerContext,
)
from pymodbus.server import (
    ModbusSerialServer,
    ModbusTcpServer,
    ModbusTlsServer,
    ModbusUdpServer,
)

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


async def serve_announced(server: ModbusTcpServer | ModbusTlsServer, port: int) -> None:
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


def tls_server_context(d: Path) -> ssl.SSLContext:
    """A Modbus/TCP Security server's context: ``d``'s server certificate,
    client certificates required and signed by ``d/ca.pem``."""
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    ctx.minimum_version = ssl.TLSVersion.TLSv1_2
    ctx.load_cert_chain(d / "server.pem", d / "server.key")
    ctx.load_verify_locations(d / "ca.pem")
    ctx.verify_mode = ssl.CERT_REQUIRED
    return ctx


def null_modem() -> tuple[str, str]:
    """Two raw pseudo-terminals joined by a thread that copies each one's
    bytes to the other: (the server's path, the client's path)."""
    ends = []
    for _ in range(2):
        master, slave = os.openpty()
        tty.setraw(master)
        tty.setraw(slave)
        ends.append((master, slave, os.ttyname(slave)))
    a, b = ends[0][0], ends[1][0]

    def copy() -> None:
        while True:
            ready, _, _ = select.select([a, b], [], [])
            for fd in ready:
                try:
                    data = os.read(fd, 1024)
                except OSError:  # the other end is not open (yet): nothing to copy
                    continue
                os.write(b if fd == a else a, data)

    threading.Thread(target=copy, daemon=True).start()
    return ends[0][2], ends[1][2]


async def main(mode: str, *args: str) -> None:
    port = free_port()
    context = ModbusServerContext(devices={1: device(), 17: device()}, single=False)
    if mode == "tls":
        tls = ModbusTlsServer(context, identity=ModbusDeviceIdentification(info_name=IDENTITY),
                              address=("127.0.0.1", port),
                              sslctx=tls_server_context(Path(args[0])))
        await serve_announced(tls, port)
        return
    identity = ModbusDeviceIdentification(info_name=IDENTITY)
    if mode == "udp":
        udp = ModbusUdpServer(context, identity=identity, address=("127.0.0.1", port))
        task = asyncio.create_task(udp.serve_forever())
        probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        probe.settimeout(0.1)
        probe.connect(("127.0.0.1", port))
        for _ in range(100):  # until a read of register 0 is answered
            await asyncio.sleep(0.02)
            try:
                probe.send(bytes.fromhex("000100000006010300000001"))
                if probe.recv(300):
                    break
            except OSError:
                continue
        probe.close()
        print("READY", port, flush=True)
        await task
        return
    if mode == "ascii":
        server_path, client_path = null_modem()
        serial = ModbusSerialServer(context, framer=FramerType.ASCII, identity=identity,
                                    port=server_path, baudrate=19200)
        task = asyncio.create_task(serial.serve_forever())
        for _ in range(250):  # until the server has the port open
            await asyncio.sleep(0.02)
            if serial.transport is not None:
                break
        await asyncio.sleep(0.2)
        print("READY", client_path, flush=True)
        await task
        return
    server = ModbusTcpServer(
        context,
        framer=FramerType.RTU if mode == "rtu-over-tcp" else FramerType.SOCKET,
        identity=identity,
        address=("127.0.0.1", port),
    )
    await serve_announced(server, port)


if __name__ == "__main__":
    asyncio.run(main(*sys.argv[1:]))
