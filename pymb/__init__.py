"""pymb: Modbus RTU for real devices, fast.

A cffi binding over libmodbus with pymb's own C core (CRC-16, frame checks,
the request path, the map decoder). The low-level API::

    import pymb
    with pymb.RtuClient("/dev/ttyUSB0", 9600, slave=40) as client:
        regs = client.read_input_registers(0, 8)      # array('H')

Errors are rooted at :class:`pymb.ModbusError`.
"""

from __future__ import annotations

from pymb._native import LIBMODBUS_VERSION, VERSION, crc16
from pymb.client import (
    AsciiClient,
    Client,
    RtuClient,
    RtuOverTcpClient,
    TcpClient,
    TlsConfig,
    UdpClient,
)
from pymb.errors import (
    Acknowledge,
    DeviceBusy,
    DeviceException,
    DeviceFailure,
    GatewayPathUnavailable,
    GatewayTargetFailed,
    IllegalDataAddress,
    IllegalDataValue,
    IllegalFunction,
    InvalidArgument,
    MemoryParityError,
    ModbusConnectionError,
    ModbusError,
    ModbusTimeout,
    NegativeAcknowledge,
    ProtocolError,
    TlsError,
    WriteNotApplied,
    WriteRefused,
)

__version__ = VERSION  # csrc/pymb.h is the one home of the version

__all__ = [
    "LIBMODBUS_VERSION",
    "Acknowledge",
    "AsciiClient",
    "Client",
    "DeviceBusy",
    "DeviceException",
    "DeviceFailure",
    "GatewayPathUnavailable",
    "GatewayTargetFailed",
    "IllegalDataAddress",
    "IllegalDataValue",
    "IllegalFunction",
    "InvalidArgument",
    "MemoryParityError",
    "ModbusConnectionError",
    "ModbusError",
    "ModbusTimeout",
    "NegativeAcknowledge",
    "ProtocolError",
    "RtuClient",
    "RtuOverTcpClient",
    "TcpClient",
    "TlsConfig",
    "TlsError",
    "UdpClient",
    "WriteNotApplied",
    "WriteRefused",
    "__version__",
    "crc16",
]
