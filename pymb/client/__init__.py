"""Modbus clients: :class:`RtuClient` (serial line), :class:`TcpClient`,
:class:`RtuOverTcpClient`, :class:`AsciiClient` and :class:`UdpClient`.

Every argument is checked before anything is sent. Reads longer than one
request allows (125 registers, 2000 bits) are split into maximal requests
that fill one preallocated array, in C. One client may be shared by threads:
each holds a lock per request, and the blocking I/O runs with the GIL
released, so other buses keep working.

Replies are checked by pymb itself (over TCP the transaction id, protocol
id, length and unit id of its own MBAP header; over RTU the CRC and address;
then function code, byte count, write echo). A failed call returns within its
timeout; over RTU the next request to that address first waits until the
line has been silent for the response timeout since the failure, so a late
or stray reply is never taken as a later answer (docs/library.md, "No stale data").
"""

from __future__ import annotations

from pymb.client.address import client_for_address, parse_host_port, unresolved
from pymb.client.base import Client
from pymb.client.checks import (
    FC,
    MAX_READ_BITS,
    MAX_READ_REGISTERS,
    MAX_WR_READ_REGISTERS,
    MAX_WR_WRITE_REGISTERS,
    MAX_WRITE_BITS,
    MAX_WRITE_REGISTERS,
)
from pymb.client.listener import LineListener
from pymb.client.tls import MBAPS_PORT, TlsConfig
from pymb.client.transports import (
    AsciiClient,
    RtuClient,
    RtuOverTcpClient,
    TcpClient,
    UdpClient,
)

__all__ = [
    "FC",
    "MAX_READ_BITS",
    "MAX_READ_REGISTERS",
    "MAX_WRITE_BITS",
    "MAX_WRITE_REGISTERS",
    "MAX_WR_READ_REGISTERS",
    "MAX_WR_WRITE_REGISTERS",
    "MBAPS_PORT",
    "AsciiClient",
    "Client",
    "LineListener",
    "RtuClient",
    "RtuOverTcpClient",
    "TcpClient",
    "TlsConfig",
    "UdpClient",
    "client_for_address",
    "parse_host_port",
    "unresolved",
]
