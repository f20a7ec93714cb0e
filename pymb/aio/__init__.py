"""pymb for asyncio programs: the same clients and device facades, awaited.

::

    import pymb.aio
    async with pymb.aio.AsyncRtuClient("/dev/ttyUSB0", 9600, slave=40) as client:
        regs = await client.read_input_registers(0, 8)      # array('H')
        hub = pymb.aio.AsyncSensorHub(client, 1)
        async for reading in hub.poll(1.0):
            ...

Every client has one worker thread that owns its line: the requests run
there, in order, in the C core (which keeps the wire timing and releases the
GIL), and the event loop never blocks. Methods, arguments, results and
exceptions are those of :mod:`pymb.client` and :mod:`pymb.devices`.
Cancellation and shutdown: see :mod:`pymb.aio.client` and ``docs/asyncio.md``.
"""

from __future__ import annotations

from pymb.aio.client import (
    AsyncAsciiClient,
    AsyncClient,
    AsyncRtuClient,
    AsyncRtuOverTcpClient,
    AsyncTcpClient,
    AsyncUdpClient,
)
from pymb.aio.devices import AsyncCoolPro, AsyncMapDevice, AsyncSensorHub, poll

__all__ = [
    "AsyncAsciiClient",
    "AsyncClient",
    "AsyncCoolPro",
    "AsyncMapDevice",
    "AsyncRtuClient",
    "AsyncRtuOverTcpClient",
    "AsyncSensorHub",
    "AsyncTcpClient",
    "AsyncUdpClient",
    "poll",
]
