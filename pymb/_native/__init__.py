"""The low-level layer: the only package that touches cffi's ``ffi`` and
``lib``. ``pymb.errors`` takes the exception codes and the C library's words
from here, ``pymb.maps`` its decoder's table from :mod:`pymb._native.mapdecode`.

Allocate, call, check, return: everything above sees Python objects, arrays
and pymb's exceptions. Calls into the extension release the GIL (cffi's API
mode does so for every call), so other threads and other buses keep working
while one waits on its line. This module holds the constants as the compiler
knows them and the byte-level helpers, and imports none of its submodules
(which import ``pymb.errors``, itself above this module): :mod:`pymb._native.link`
the line, :mod:`pymb._native.transports` one factory a transport,
:mod:`pymb._native.mapdecode` the map decoder, :mod:`pymb._native.master` and
:mod:`pymb._native.serve` the sans-I/O master and server, :mod:`pymb._native.tls`
TLS under a line.
"""

from __future__ import annotations

import os
import sys
from array import array
from enum import IntEnum
from typing import Any, TypeAlias

try:
    from pymb._pymb_cffi import ffi, lib
except ModuleNotFoundError as e:
    if e.name != "pymb._pymb_cffi":
        raise
    # A clone's source tree found before the installed pymb (``python -m
    # pymb`` run inside the clone after ``pip install .``): say so.
    _TREE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    _WHY = (f"pymb: {_TREE} is pymb's source tree, and its C extension is not built there: "
            "run pymb from another folder, or install this clone editable (pip install -e .)")
    if getattr(sys, "argv", [])[:1] == ["-m"]:  # python -m pymb: the command's one line, exit 2
        sys.stderr.write(_WHY + "\n")
        raise SystemExit(2) from None
    raise ImportError(_WHY) from None  # a program's import: for it to catch

__all__ = [
    "BAUD_RATES",
    "FRAME_INCOMPLETE",
    "LIBMODBUS_VERSION",
    "MAX_PDU_DATA",
    "MAX_READ_BITS",
    "MAX_READ_REGISTERS",
    "MAX_WRITE_BITS",
    "MAX_WRITE_REGISTERS",
    "MAX_WR_READ_REGISTERS",
    "MAX_WR_WRITE_REGISTERS",
    "RTS_MODES",
    "SERIAL_MODES",
    "VERSION",
    "DeviceExceptionCode",
    "FunctionCode",
    "ProtocolErrno",
    "State",
    "crc16",
    "errno_exception",
    "exception_errno",
    "exception_strerror",
    "rtu_crc_ok",
    "rtu_request_length",
    "rtu_response_length",
    "rtu_silence",
    "strerror",
    "with_crc",
]

#: pymb's version, as the compiled C library (csrc/pymb.h, its one home) says it.
VERSION: str = ffi.string(lib.pymb_version()).decode()

LIBMODBUS_VERSION = (
    f"{lib.libmodbus_version_major}.{lib.libmodbus_version_minor}."
    f"{lib.libmodbus_version_micro}"
)

#: Baud rates libmodbus 3.1.6 maps to termios speeds; any other it silently
#: replaces with 9600, so pymb refuses it instead.
BAUD_RATES = frozenset(
    (110, 300, 600, 1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200, 230400, 460800,
     500000, 576000, 921600, 1000000, 1152000, 1500000, 2500000, 3000000, 3500000, 4000000)
)

_from_buffer = ffi.from_buffer
_NULL = ffi.NULL


# -- constants, as the compiler knows them (build_ffi.py declares them "...") ----


class FunctionCode(IntEnum):
    """Modbus function codes ([MB-AP] 6), as libmodbus's ``modbus.h`` defines them."""

    READ_COILS = lib.MODBUS_FC_READ_COILS
    READ_DISCRETE_INPUTS = lib.MODBUS_FC_READ_DISCRETE_INPUTS
    READ_HOLDING_REGISTERS = lib.MODBUS_FC_READ_HOLDING_REGISTERS
    READ_INPUT_REGISTERS = lib.MODBUS_FC_READ_INPUT_REGISTERS
    WRITE_SINGLE_COIL = lib.MODBUS_FC_WRITE_SINGLE_COIL
    WRITE_SINGLE_REGISTER = lib.MODBUS_FC_WRITE_SINGLE_REGISTER
    READ_EXCEPTION_STATUS = lib.MODBUS_FC_READ_EXCEPTION_STATUS
    WRITE_MULTIPLE_COILS = lib.MODBUS_FC_WRITE_MULTIPLE_COILS
    WRITE_MULTIPLE_REGISTERS = lib.MODBUS_FC_WRITE_MULTIPLE_REGISTERS
    REPORT_SLAVE_ID = lib.MODBUS_FC_REPORT_SLAVE_ID
    MASK_WRITE_REGISTER = lib.MODBUS_FC_MASK_WRITE_REGISTER
    WRITE_AND_READ_REGISTERS = lib.MODBUS_FC_WRITE_AND_READ_REGISTERS


class DeviceExceptionCode(IntEnum):
    """The exception codes [MB-AP] 7 defines, as libmodbus's ``modbus.h`` numbers them."""

    ILLEGAL_FUNCTION = lib.MODBUS_EXCEPTION_ILLEGAL_FUNCTION
    ILLEGAL_DATA_ADDRESS = lib.MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS
    ILLEGAL_DATA_VALUE = lib.MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE
    SLAVE_OR_SERVER_FAILURE = lib.MODBUS_EXCEPTION_SLAVE_OR_SERVER_FAILURE
    ACKNOWLEDGE = lib.MODBUS_EXCEPTION_ACKNOWLEDGE
    SLAVE_OR_SERVER_BUSY = lib.MODBUS_EXCEPTION_SLAVE_OR_SERVER_BUSY
    NEGATIVE_ACKNOWLEDGE = lib.MODBUS_EXCEPTION_NEGATIVE_ACKNOWLEDGE
    MEMORY_PARITY = lib.MODBUS_EXCEPTION_MEMORY_PARITY
    GATEWAY_PATH = lib.MODBUS_EXCEPTION_GATEWAY_PATH
    GATEWAY_TARGET = lib.MODBUS_EXCEPTION_GATEWAY_TARGET


class ProtocolErrno(IntEnum):
    """libmodbus's errno values for a reply that is not the answer (modbus.h),
    which the C core's request path sets as libmodbus does."""

    BAD_CRC = lib.EMBBADCRC
    BAD_DATA = lib.EMBBADDATA
    BAD_EXCEPTION = lib.EMBBADEXC
    UNKNOWN_EXCEPTION = lib.EMBUNKEXC
    TOO_MANY_DATA = lib.EMBMDATA
    BAD_SLAVE = lib.EMBBADSLAVE


def strerror(err: int) -> str:
    """The C library's words for an errno value (``pymb_strerror``): the
    exceptions as [MB-AP] 7 names them, libmodbus's protocol errors, the
    OS's ``strerror`` for the rest."""
    text: str = ffi.string(lib.pymb_strerror(err)).decode()
    return text


def exception_errno(code: int) -> int:
    """The errno a request fails with when the device answers exception
    ``code`` (1..255) (``pymb_exception_errno``)."""
    return int(lib.pymb_exception_errno(code))


def exception_strerror(code: int) -> str:
    """``strerror`` of the errno a request fails with when the device answers
    exception ``code`` (1..255)."""
    return strerror(exception_errno(code))


def errno_exception(err: int) -> int:
    """The exception code (1..255) an errno value stands for, 0 when it is
    none (``pymb_errno_exception``)."""
    return int(lib.pymb_errno_exception(err))


#: Quantities one request may carry ([MB-AP] 6.1..6.17, libmodbus's modbus.h).
MAX_READ_BITS = int(lib.PYMB_MAX_READ_BITS)
MAX_WRITE_BITS = int(lib.MODBUS_MAX_WRITE_BITS)
MAX_READ_REGISTERS = int(lib.PYMB_MAX_READ_REGISTERS)
MAX_WRITE_REGISTERS = int(lib.MODBUS_MAX_WRITE_REGISTERS)
MAX_WR_WRITE_REGISTERS = int(lib.MODBUS_MAX_WR_WRITE_REGISTERS)
MAX_WR_READ_REGISTERS = int(lib.MODBUS_MAX_WR_READ_REGISTERS)
#: Data bytes one PDU carries after its function code ([MB-AP] 4.1: 253 - 1).
MAX_PDU_DATA = int(lib.PYMB_MAX_PDU) - 1

#: libmodbus's serial modes and RTS modes, by the names the client takes.
SERIAL_MODES = {"rs232": int(lib.MODBUS_RTU_RS232), "rs485": int(lib.MODBUS_RTU_RS485)}
RTS_MODES = {"none": int(lib.MODBUS_RTU_RTS_NONE), "up": int(lib.MODBUS_RTU_RTS_UP),
             "down": int(lib.MODBUS_RTU_RTS_DOWN)}

#: pymb_rtu_request_length / pymb_rtu_response_length: more bytes are needed.
FRAME_INCOMPLETE = int(lib.PYMB_FRAME_INCOMPLETE)


class State(IntEnum):
    """Why a decoded value is (or is not) there; see [NOTES] "offline vs absent"
    (``pymb_state`` in csrc/pymb.h)."""

    VALUE = lib.PYMB_VALUE  #: a value
    OFFLINE = lib.PYMB_OFFLINE  #: 0xFFFF: the channel is offline (or has no such value)
    NO_SENSOR = lib.PYMB_NO_SENSOR  #: the humidity "no humidity" marker of the channel's unit
    UNSUPPORTED = lib.PYMB_UNSUPPORTED  #: the hub's firmware does not have this block
    NOT_READ = lib.PYMB_NOT_READ  #: not asked for in this read


#: What the byte-level helpers take: any contiguous buffer (collections.abc.Buffer
#: from Python 3.12 on).
Buffer: TypeAlias = "bytes | bytearray | memoryview | array[Any]"


def _bytes_arg(data: Any) -> tuple[Any, int]:
    """A buffer as C sees it: its bytes and its length in *bytes* (an array of
    16-bit items is twice its len()). bytes go to C as they are (the fast
    path); other contiguous buffers through from_buffer; a non-contiguous
    view is copied in its logical order."""
    if type(data) is bytes:
        return data, len(data)
    try:
        view = memoryview(data)
    except TypeError:
        raise TypeError(
            f"expected bytes or a buffer, got {type(data).__name__}") from None
    if not view.c_contiguous:
        b = view.tobytes()
        return b, len(b)
    return ffi.from_buffer("uint8_t[]", view), view.nbytes


def crc16(data: Buffer) -> int:
    """CRC-16/MODBUS of the bytes of ``data`` (as it goes on the wire: low
    byte first). Any buffer: its whole byte length counts."""
    buf, n = _bytes_arg(data)
    return int(lib.pymb_crc16(buf, n))


def with_crc(frame: Buffer) -> bytes:
    """``frame`` with its CRC appended, low byte first (an RTU frame)."""
    buf, n = _bytes_arg(frame)
    crc = lib.pymb_crc16(buf, n)
    head = buf if type(buf) is bytes else bytes(ffi.buffer(buf, n))
    return head + bytes((crc & 0xFF, crc >> 8))


def rtu_crc_ok(frame: Buffer) -> bool:
    """True when the last two bytes of ``frame`` are the CRC of the rest."""
    return bool(lib.pymb_rtu_crc_ok(*_bytes_arg(frame)))


def rtu_request_length(buf: Buffer) -> int:
    """Length of the RTU request starting ``buf`` as its header tells it:
    -1 needs more bytes, -4 unknown function (only silence ends it), -7 too
    long (see pymb_rtu_request_length in csrc/pymb.h)."""
    return int(lib.pymb_rtu_request_length(*_bytes_arg(buf)))


def rtu_response_length(buf: Buffer) -> int:
    """Length of the RTU response starting ``buf`` (-1: need more bytes, -4:
    a function code whose reply length only the line's silence tells)."""
    return int(lib.pymb_rtu_response_length(*_bytes_arg(buf)))


def rtu_silence(baudrate: int) -> float:
    """t3.5 at ``baudrate`` in seconds ([MB-SL] 2.5.1.1; 1.75 ms above 19200)."""
    return int(lib.pymb_rtu_silence_us(baudrate)) / 1e6
