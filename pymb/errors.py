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
as :mod:`pymb._native` reads it from the compiled extension
(:class:`~pymb._native.DeviceExceptionCode`), never typed here; their names are the
C library's (``pymb_strerror``), their one home. This module sits between
``pymb._native`` (its constants, which import nothing of pymb) and the line
(``pymb._native.link``, which raises these exceptions).
The messages of a failed request are written here too
(:func:`request_error`), from what ``pymb._native`` hands up.
"""

from __future__ import annotations

import difflib
import errno as _errno
import os
from collections.abc import Iterable
from typing import Any, ClassVar, TypedDict

from pymb._native import (
    DeviceExceptionCode,
    FunctionCode,
    ProtocolErrno,
    errno_exception,
    exception_strerror,
)

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
    "TlsError",
    "WriteNotApplied",
    "WriteRefused",
    "closest_hint",
    "describe_exception",
    "exception_class",
    "function_name",
    "os_hint",
    "request_error",
    "request_text",
]


def describe_exception(code: int) -> str:
    """The name of Modbus exception ``code`` ([MB-AP] 7), as the C library's
    pymb_strerror gives it, in lower case: "illegal data address"."""
    text = exception_strerror(code)
    return text[:1].lower() + text[1:]


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


class TlsError(ModbusConnectionError):
    """Modbus/TCP Security (``mbaps://``) failed: the server's certificate
    was refused (expired, not signed by a CA trusted, made for another
    name), the server refused this client or its certificate, or the port
    does not speak TLS. The message says which, in one line."""


class InvalidArgument(ModbusError, ValueError):
    """An argument is out of range; raised before anything is sent."""


class WriteRefused(ModbusError):
    """A write refused by a policy (the point's write budget, the allow
    list); nothing was sent. ``reason`` names the policy (``"budget"``,
    ``"not_allowed"``), ``point`` the point."""

    def __init__(self, message: str, *, reason: str = "budget", point: str | None = None,
                 **kw: object) -> None:
        super().__init__(message, **kw)  # type: ignore[arg-type]
        self.reason = reason
        self.point = point


class WriteNotApplied(ModbusError):
    """The device answered a write but, read back, holds another value.

    ``point`` names the point, ``sent`` the value written and ``found`` the
    value read back; ``applied`` maps the points of the same command that
    the device did apply to their values read back."""

    def __init__(self, message: str, *, point: str | None = None, sent: object = None,
                 found: object = None, applied: dict[str, Any] | None = None,
                 **kw: object) -> None:
        super().__init__(message, **kw)  # type: ignore[arg-type]
        self.point = point
        self.sent = sent
        self.found = found
        self.applied = dict(applied or {})
        #: what became of every value of the command (:class:`pymb.devices.mapwrite.Outcome`)
        self.outcomes: list[Any] = []


class OutputError(Exception):
    """Logged data could not be written (disk full, read-only database or
    file, I/O error). What was committed before is intact; the batch being
    written when it happened is lost."""


#: exception code -> the DeviceException subclass of a standard code (filled by each)
_BY_CODE: dict[int, type[DeviceException]] = {}


class DeviceException(ModbusError):
    """The device answered with a Modbus exception response.

    ``code`` is the exception code (1..255). Subclasses name the standard codes
    (Modbus Application Protocol V1.1b3, section 7); any other code (09, not
    defined there, and 0C..FF) raises this class itself, with ``code`` set.
    """

    default_code: ClassVar[int] = 0
    description: ClassVar[str] = "exception"
    code: int

    def __init_subclass__(cls, *, code: DeviceExceptionCode | None = None, **kw: Any) -> None:
        """A subclass for a standard ``code``: its number, its description,
        and :func:`exception_class`'s answer for it."""
        super().__init_subclass__(**kw)
        if code is not None:
            cls.default_code = int(code)
            cls.description = describe_exception(code)
            _BY_CODE[cls.default_code] = cls

    def __init__(self, message: str, *, code: int | None = None, **kw: object) -> None:
        super().__init__(message, **kw)  # type: ignore[arg-type]
        self.code = self.default_code if code is None else code


class IllegalFunction(DeviceException, code=DeviceExceptionCode.ILLEGAL_FUNCTION):
    """Exception 01: the device does not support the function code."""


class IllegalDataAddress(DeviceException, code=DeviceExceptionCode.ILLEGAL_DATA_ADDRESS):
    """Exception 02: the address, or address plus count, is not valid for the
    device (the sensor hub also answers 02 for a block its firmware lacks)."""


class IllegalDataValue(DeviceException, code=DeviceExceptionCode.ILLEGAL_DATA_VALUE):
    """Exception 03: a value in the request is out of range."""


class DeviceFailure(DeviceException, code=DeviceExceptionCode.SLAVE_OR_SERVER_FAILURE):
    """Exception 04: the device failed while processing the request
    (the standard meaning; the sensor hub uses 04 for busy, see DeviceBusy)."""


class Acknowledge(DeviceException, code=DeviceExceptionCode.ACKNOWLEDGE):
    """Exception 05: accepted, but it will take long; poll again later."""


class DeviceBusy(DeviceException, code=DeviceExceptionCode.SLAVE_OR_SERVER_BUSY):
    """The device is busy (standard code 06; the sensor hub's code 04).
    Worth a retry after a short wait."""


class NegativeAcknowledge(DeviceException, code=DeviceExceptionCode.NEGATIVE_ACKNOWLEDGE):
    """Exception 07: the device cannot perform the program function."""


class MemoryParityError(DeviceException, code=DeviceExceptionCode.MEMORY_PARITY):
    """Exception 08: the device found a parity error in its memory."""


class GatewayPathUnavailable(DeviceException, code=DeviceExceptionCode.GATEWAY_PATH):
    """Exception 0A: the gateway has no path to the target."""


class GatewayTargetFailed(DeviceException, code=DeviceExceptionCode.GATEWAY_TARGET):
    """Exception 0B: the gateway's target did not respond."""


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
    if err == _errno.ETIMEDOUT:
        return ("no answer to the connection request within the timeout (is the host up? "
                "a firewall may drop it)")
    if err == _errno.ENOTTY:
        return "not a serial port (a terminal device such as /dev/ttyUSB0 is needed)"
    return os.strerror(err)


def closest_hint(word: str, known: Iterable[str], cutoff: float = 0.5) -> str:
    """``; did you mean 'x'?`` with the name in ``known`` closest to ``word``
    (difflib's ratio at least ``cutoff``), or "" when none is that close."""
    near = difflib.get_close_matches(word, list(known), n=1, cutoff=cutoff)
    return f"; did you mean {near[0]!r}?" if near else ""


# The names messages give a request: the client's method names.
_FUNCTION_NAMES: dict[int, str] = {
    FunctionCode.READ_COILS: "read_coils",
    FunctionCode.READ_DISCRETE_INPUTS: "read_discrete_inputs",
    FunctionCode.READ_HOLDING_REGISTERS: "read_holding_registers",
    FunctionCode.READ_INPUT_REGISTERS: "read_input_registers",
    FunctionCode.WRITE_SINGLE_COIL: "write_coil",
    FunctionCode.WRITE_SINGLE_REGISTER: "write_register",
    FunctionCode.READ_EXCEPTION_STATUS: "read_exception_status",
    FunctionCode.WRITE_MULTIPLE_COILS: "write_coils",
    FunctionCode.WRITE_MULTIPLE_REGISTERS: "write_registers",
    FunctionCode.REPORT_SLAVE_ID: "report_slave_id",
    FunctionCode.MASK_WRITE_REGISTER: "mask_write_register",
    FunctionCode.WRITE_AND_READ_REGISTERS: "write_read_registers",
}
_READS = frozenset((FunctionCode.READ_COILS, FunctionCode.READ_DISCRETE_INPUTS,
                    FunctionCode.READ_HOLDING_REGISTERS, FunctionCode.READ_INPUT_REGISTERS))


def function_name(function: int) -> str:
    """What messages call a request of ``function``: the client method's name."""
    return _FUNCTION_NAMES.get(function, f"function 0x{function:02X}")


def request_text(function: int, slave: int, address: int | None = None,
                 count: int | None = None, context: str | None = None) -> str:
    """A request as errors name it: ``read_input_registers(slave=1,
    address=0, count=4)`` (``context``: another name before the parentheses)."""
    args = [f"slave={slave}"]
    if address is not None:
        args.append(f"address={address}")
    if count is not None:
        args.append(f"count={count}")
    return f"{context or function_name(function)}({', '.join(args)})"


def _hex(data: bytes) -> str:
    return " ".join(f"{b:02X}" for b in data)


def closed_error(function: int, slave: int, address: int | None, count: int | None,
                 port: str) -> ModbusConnectionError:
    """A request on a line that is not open."""
    return ModbusConnectionError(
        f"{function_name(function)}(slave={slave}) on {port}: the port is not open",
        errno=_errno.EBADF, slave=slave, function=function, address=address, count=count,
        port=port,
    )


def stopped_error(function: int, slave: int, address: int | None, count: int | None,
                  port: str, *, sent: bool = True) -> ModbusConnectionError:
    """A request that was waiting when another thread or task closed its
    client; ``sent`` False: one whose turn came after that close began, never
    sent."""
    when = "while this request waited" if sent else "before this request was sent"
    return ModbusConnectionError(
        f"{request_text(function, slave, address, count)} on {port}: the client was closed "
        f"{when}", errno=_errno.ECANCELED, slave=slave, function=function,
        address=address, count=count, port=port,
    )


class _Asked(TypedDict):
    """What every error of a failed request carries about it."""

    slave: int
    function: int
    address: int | None
    count: int | None
    port: str
    response: bytes | None


def request_error(err: int, *, function: int, slave: int, address: int | None,
                  count: int | None, port: str, timeout: float, failed: tuple[int, int],
                  response: bytes | None, header: int, frame: str | None,
                  context: str | None = None, tls: str | None = None,
                  checksum: str = "CRC", sends: int = 1, dropped: bool = False) -> ModbusError:
    """The exception for a request that failed with errno ``err``: what was
    asked, what came back (``response``, its unit id at ``header - 1``),
    ``failed`` the (address, count) of the request that failed inside a
    longer read, ``frame`` the C library's words for a rejected reply,
    ``tls`` the words of a TLS failure under the line,
    ``checksum`` the frame check's name (ASCII: ``"LRC"``), ``sends`` how
    often the request went out (UDP's retries), ``dropped``: on a timeout,
    ``response`` is a whole frame that was no answer (``frame`` says why),
    not the start of one."""
    asked = f"{request_text(function, slave, address, count, context)} on {port}"
    if function in _READS and failed[1] >= 0 and failed != (address, count):
        asked += f" [in the request for {failed[1]} at {failed[0]}]"
    got = response or None
    received = f" (received {_hex(got)})" if got else ""
    if address is None and function in _READS and failed[1] >= 0:
        address, count = failed
    kw = _Asked(slave=slave, function=function, address=address, count=count, port=port,
                response=got)
    if tls is not None:
        return TlsError(f"{asked}: {tls}", errno=err, **kw)
    if err == _errno.ETIMEDOUT:
        within = f"within the {timeout:g} s timeout" + (
            f" to any of {sends} sends" if sends > 1 else "")
        if got and dropped:
            return ModbusTimeout(
                f"{asked}: no reply {within}; what came was not the answer: "
                f"{frame or 'dropped'}{received}", **kw)
        if got:
            return ModbusTimeout(
                f"{asked}: the reply was incomplete after {len(got)} bytes, {within}"
                f"{received}", **kw)
        return ModbusTimeout(
            f"{asked}: no reply {within} (the device is silent, "
            "or the address, baud rate or wiring is wrong)", **kw)
    code = errno_exception(err)
    if code:
        return exception_class(code)(
            f"{asked}: device answered exception {code:02X} ({describe_exception(code)})"
            f"{received}", code=code, **kw)
    if err == ProtocolErrno.BAD_CRC:
        return ProtocolError(f"{asked}: reply failed its {checksum} check{received}",
                             reason=f"bad {checksum}", **kw)
    if err == ProtocolErrno.BAD_SLAVE:
        h = header if 1 <= header <= len(got or b"") else 0
        who = f" {got[h - 1]}" if got and h else ""
        return ProtocolError(f"{asked}: reply came from another address{who}{received}",
                             reason="wrong slave", **kw)
    if err == ProtocolErrno.BAD_EXCEPTION:
        return ProtocolError(f"{asked}: reply is an invalid exception response{received}",
                             reason="invalid exception", **kw)
    if err in (ProtocolErrno.BAD_DATA, ProtocolErrno.TOO_MANY_DATA,
               ProtocolErrno.UNKNOWN_EXCEPTION):
        why = frame or "malformed reply"
        return ProtocolError(f"{asked}: {why}{received}", reason=why, **kw)
    if err == _errno.EINVAL:
        return InvalidArgument(f"{asked}: invalid argument", **kw)
    if err == _errno.EINTR:
        return ModbusConnectionError(f"{asked}: interrupted", errno=err, **kw)
    return ModbusConnectionError(f"{asked}: {os_hint(err)}", errno=err, **kw)
