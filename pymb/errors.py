"""pymb's exceptions: one small hierarchy rooted at :class:`ModbusError`.

``ModbusError`` is never raised itself. What the *device* reported is a
:class:`DeviceException`: a subclass for each exception code the Modbus
specification defines (01..08, 0A, 0B), ``DeviceException`` itself, with
``.code``, for any other code (09, and 0C..FF: vendors' own codes); an
exception response with code 00 is no valid reply, a :class:`ProtocolError`.
What the *master* saw is a :class:`ModbusTimeout`, a :class:`ProtocolError`
or a :class:`ModbusConnectionError`; a bad argument, caught before any I/O,
is an :class:`InvalidArgument`. Every message says what was asked (slave, function,
address, count, port) and what came back.

The codes come from the compiler: libmodbus's ``MODBUS_EXCEPTION_*`` enum,
read from the compiled extension (this module sits below ``pymb._native``,
which imports it, so it reads ``pymb._pymb_cffi.lib`` itself), never typed
here.
"""

from __future__ import annotations

import errno as _errno
import os
from typing import ClassVar

from pymb._pymb_cffi import lib as _lib

__all__ = [
    "Acknowledge",
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
    "OutputError",
    "ProtocolError",
    "exception_class",
]


class ModbusError(Exception):
    """Root of every error pymb raises; catch this to catch them all.

    Attributes (``None`` where they do not apply): ``slave``, ``function``,
    ``address``, ``count`` of the request, ``port`` it went to, and
    ``response``, the bytes that came back.
    """

    slave: int | None
    function: int | None
    address: int | None
    count: int | None
    port: str | None
    response: bytes | None

    def __init__(
        self,
        message: str,
        *,
        slave: int | None = None,
        function: int | None = None,
        address: int | None = None,
        count: int | None = None,
        port: str | None = None,
        response: bytes | None = None,
    ) -> None:
        super().__init__(message)
        self.slave = slave
        self.function = function
        self.address = address
        self.count = count
        self.port = port
        self.response = response

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""


class ModbusTimeout(ModbusError, TimeoutError):
    """No complete reply arrived within the client's timeout."""


class ProtocolError(ModbusError):
    """A reply arrived but is not a valid answer to the request: bad CRC,
    another slave's address, another function code, a byte count or length
    that does not match, a write echo that differs, a malformed frame.

    ``reason`` names which, in a few words.
    """

    reason: str

    def __init__(self, message: str, *, reason: str = "invalid reply", **kw: object) -> None:
        super().__init__(message, **kw)  # type: ignore[arg-type]
        self.reason = reason


class ModbusConnectionError(ModbusError, ConnectionError):
    """The operating system failed the link: the port does not exist or was
    unplugged (``EIO``), permission was denied, the port is in use, the TCP
    peer refused or reset the connection. ``errno`` is the OS's error number
    and ``port`` names the device or address."""

    def __init__(self, message: str, *, errno: int | None = None, **kw: object) -> None:
        super().__init__(message, **kw)  # type: ignore[arg-type]
        self.errno = errno


class InvalidArgument(ModbusError, ValueError):
    """An argument is out of range; raised before anything is sent."""


class OutputError(Exception):
    """Logged data could not be written (disk full, read-only database or
    file, I/O error). What was committed before is intact; the batch being
    written when it happened is lost."""


class DeviceException(ModbusError):
    """The device answered with a Modbus exception response.

    ``code`` is the exception code (1..255). Subclasses name the standard codes
    (Modbus Application Protocol V1.1b3, section 7); any other code (09, not
    defined there, and 0C..FF) raises this class itself, with ``code`` set.
    """

    default_code: ClassVar[int] = 0
    description: ClassVar[str] = "exception"
    code: int

    def __init__(self, message: str, *, code: int | None = None, **kw: object) -> None:
        super().__init__(message, **kw)  # type: ignore[arg-type]
        self.code = self.default_code if code is None else code


class IllegalFunction(DeviceException):
    """Exception 01: the device does not support the function code."""

    default_code = _lib.MODBUS_EXCEPTION_ILLEGAL_FUNCTION
    description = "illegal function"


class IllegalDataAddress(DeviceException):
    """Exception 02: the address, or address plus count, is not valid for the
    device (the sensor hub also answers 02 for a block its firmware lacks)."""

    default_code = _lib.MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS
    description = "illegal data address"


class IllegalDataValue(DeviceException):
    """Exception 03: a value in the request is out of range."""

    default_code = _lib.MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE
    description = "illegal data value"


class DeviceFailure(DeviceException):
    """Exception 04: the device failed while processing the request
    (the standard meaning; the sensor hub uses 04 for busy, see DeviceBusy)."""

    default_code = _lib.MODBUS_EXCEPTION_SLAVE_OR_SERVER_FAILURE
    description = "server device failure"


class Acknowledge(DeviceException):
    """Exception 05: accepted, but it will take long; poll again later."""

    default_code = _lib.MODBUS_EXCEPTION_ACKNOWLEDGE
    description = "acknowledge"


class DeviceBusy(DeviceException):
    """The device is busy (standard code 06; the sensor hub's code 04).
    Worth a retry after a short wait."""

    default_code = _lib.MODBUS_EXCEPTION_SLAVE_OR_SERVER_BUSY
    description = "server device busy"


class NegativeAcknowledge(DeviceException):
    """Exception 07: the device cannot perform the program function."""

    default_code = _lib.MODBUS_EXCEPTION_NEGATIVE_ACKNOWLEDGE
    description = "negative acknowledge"


class MemoryParityError(DeviceException):
    """Exception 08: the device found a parity error in its memory."""

    default_code = _lib.MODBUS_EXCEPTION_MEMORY_PARITY
    description = "memory parity error"


class GatewayPathUnavailable(DeviceException):
    """Exception 0A: the gateway has no path to the target."""

    default_code = _lib.MODBUS_EXCEPTION_GATEWAY_PATH
    description = "gateway path unavailable"


class GatewayTargetFailed(DeviceException):
    """Exception 0B: the gateway's target did not respond."""

    default_code = _lib.MODBUS_EXCEPTION_GATEWAY_TARGET
    description = "gateway target device failed to respond"


_BY_CODE: dict[int, type[DeviceException]] = {
    cls.default_code: cls
    for cls in (
        IllegalFunction,
        IllegalDataAddress,
        IllegalDataValue,
        DeviceFailure,
        Acknowledge,
        DeviceBusy,
        NegativeAcknowledge,
        MemoryParityError,
        GatewayPathUnavailable,
        GatewayTargetFailed,
    )
}


def exception_class(code: int) -> type[DeviceException]:
    """The DeviceException subclass for a Modbus exception code."""
    return _BY_CODE.get(code, DeviceException)


def os_hint(err: int) -> str:
    """What an OS error number means to someone opening a port or a
    connection, with the usual remedy (``os.strerror`` for the rest)."""
    if err in (_errno.EACCES, _errno.EPERM):
        return (
            "permission denied; add yourself to the group that owns the port "
            "(usually `dialout`: sudo usermod -aG dialout $USER, then log in again)"
        )
    if err in (_errno.ENOENT, _errno.ENODEV, _errno.ENXIO):
        return "no such port (is the adapter plugged in? see `ls /dev/serial/by-id/`)"
    if err == _errno.EIO:
        return "I/O error on the port (was the adapter unplugged?)"
    if err == _errno.EBUSY:
        return "the port is in use by another process"
    if err == _errno.ECONNREFUSED:
        return "connection refused (nothing is listening there)"
    if err == _errno.ECONNRESET:
        return "connection closed by the peer"
    if err == _errno.ENOTTY:
        return "not a serial port (a terminal device such as /dev/ttyUSB0 is needed)"
    return os.strerror(err)
