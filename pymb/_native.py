"""The only module that touches cffi's ``ffi`` and ``lib``.

Allocate, call, check, return: everything above this module sees Python
objects, arrays and pymb's exceptions. Calls into the extension release the
GIL (cffi's API mode does so for every call), so other threads and other
buses keep working while one waits on its line.
"""

from __future__ import annotations

import errno
import os
import socket
import struct
import threading
from array import array
from enum import IntEnum
from typing import Any, TypeAlias

from pymb._pymb_cffi import ffi, lib
from pymb.errors import (
    InvalidArgument,
    ModbusConnectionError,
    ModbusError,
    ModbusTimeout,
    ProtocolError,
    exception_class,
    os_hint,
)

__all__ = [
    "BAUD_RATES",
    "FRAME_INCOMPLETE",
    "HUB_ALL_BLOCKS",
    "HUB_BITMAP_BYTES",
    "HUB_BLOCKS",
    "HUB_CHANNELS",
    "HUB_REGISTERS",
    "LIBMODBUS_VERSION",
    "MAX_READ_BITS",
    "MAX_READ_REGISTERS",
    "MAX_WRITE_BITS",
    "MAX_WRITE_REGISTERS",
    "MAX_WR_READ_REGISTERS",
    "MAX_WR_WRITE_REGISTERS",
    "RTS_MODES",
    "SERIAL_MODES",
    "VERSION",
    "FunctionCode",
    "HubSweep",
    "Link",
    "State",
    "coolpro_identity",
    "coolpro_telemetry",
    "crc16",
    "ffi_buffer_u16",
    "hub_decode",
    "hub_plan_all",
    "rtu_crc_ok",
    "rtu_request_length",
    "rtu_response_length",
    "rtu_silence",
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

_FD_SETSIZE = int(lib.FD_SETSIZE)  # select()'s limit, which libmodbus's TCP code is bound by
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


#: Quantities one request may carry ([MB-AP] 6.1..6.17, libmodbus's modbus.h).
MAX_READ_BITS = int(lib.MODBUS_MAX_READ_BITS)
MAX_WRITE_BITS = int(lib.MODBUS_MAX_WRITE_BITS)
MAX_READ_REGISTERS = int(lib.MODBUS_MAX_READ_REGISTERS)
MAX_WRITE_REGISTERS = int(lib.MODBUS_MAX_WRITE_REGISTERS)
MAX_WR_WRITE_REGISTERS = int(lib.MODBUS_MAX_WR_WRITE_REGISTERS)
MAX_WR_READ_REGISTERS = int(lib.MODBUS_MAX_WR_READ_REGISTERS)

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


_READS = frozenset((FunctionCode.READ_COILS, FunctionCode.READ_DISCRETE_INPUTS,
                    FunctionCode.READ_HOLDING_REGISTERS, FunctionCode.READ_INPUT_REGISTERS))

# The names error messages give a request: the client's method names.
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


# -- signals -------------------------------------------------------------------
# While a request waits, C calls pymb_py_interrupted when poll() is interrupted
# by a signal and at least every PYMB_INTERRUPT_SLICE_US. Running this Python
# function lets the interpreter run the pending signal handlers (it does so on
# entering a function); a handler that raises (SIGINT's KeyboardInterrupt)
# lands in _interrupt_raised, which keeps the exception and tells C to stop.
# A handler that returns normally changes nothing: the wait goes on.

_pending = threading.local()


def _interrupt_raised(exc_type: Any, exc: BaseException | None, tb: Any) -> int:
    _pending.exc = exc if exc is not None else exc_type()
    return 1


@ffi.def_extern(onerror=_interrupt_raised)  # type: ignore[untyped-decorator]
def pymb_py_interrupted(arg: Any) -> int:
    return 0


def _take_interrupt() -> BaseException | None:
    exc: BaseException | None = getattr(_pending, "exc", None)
    _pending.exc = None
    return exc


def ffi_buffer_u16(array: Any) -> Any:
    """A ``uint16_t *`` over a writable buffer (an ``array('H')``)."""
    return ffi.from_buffer("uint16_t[]", array, require_writable=True)


def _hex(data: bytes) -> str:
    return " ".join(f"{b:02X}" for b in data)


class Link:
    """One libmodbus context: a serial line or a TCP connection.

    Not thread-safe by itself; the clients in :mod:`pymb.client` hold a lock
    around every call.
    """

    def __init__(self, name: str, factory: Any, *, serial: bool,
                 framing: int | None = None, silence: float = 0.0, char_ns: int = 0,
                 host: str | None = None) -> None:
        self.name = name
        self.host = host  # TCP: the host name or address as given
        self.serial = serial
        self._factory = factory
        self._framing = framing if framing is not None else (
            lib.PYMB_FRAMING_RTU if serial else lib.PYMB_FRAMING_TCP)
        self._silence_us = max(0, round(silence * 1e6))
        self._char_ns = char_ns  # one character's wire time (serial lines)
        self._reject_early = False
        self._ctx: Any = ffi.NULL
        #: True while a connected context exists (a plain attribute: the hot
        #: path reads it on every request).
        self.is_open = False
        #: the C line (pymb_line_new) while open, NULL when closed: a request
        #: on a closed Link fails in C with EINVAL
        self._line: Any = ffi.NULL
        self._fail = ffi.new("pymb_failure *")
        self._rsp = ffi.new("uint8_t[]", lib.MODBUS_MAX_ADU_LENGTH)
        self._header = 1  # where a reply's PDU starts: pymb_line_header_length
        self._timeout = (1.0, 0.0)
        self._rs485: tuple[int | None, int | None, int | None] = (None, None, None)

    # -- life cycle ------------------------------------------------------------

    def open(self) -> None:
        """Create the context, connect, lock the port, apply the settings."""
        if self.is_open:
            return
        if not self.serial:
            # libmodbus's TCP code waits with select(), which aborts the whole
            # process (glibc's fd_set check) on a descriptor >= FD_SETSIZE. The
            # socket will take the lowest free descriptor: look at it first.
            probe = os.open("/dev/null", os.O_RDONLY)
            os.close(probe)
            if probe >= _FD_SETSIZE:
                raise ModbusConnectionError(
                    f"cannot connect to {self.name}: this process has {probe} descriptors "
                    f"open, and libmodbus's TCP code only works below {_FD_SETSIZE}",
                    errno=errno.EMFILE, port=self.name,
                )
        ctx = self._factory()
        if ctx == ffi.NULL:
            err = ffi.errno
            raise ModbusConnectionError(
                f"cannot create a Modbus context for {self.name}: {os.strerror(err)}",
                errno=err,
                port=self.name,
            )
        if lib.modbus_connect(ctx) == -1:
            err = ffi.errno
            lib.modbus_free(ctx)
            hint = os_hint(err)
            if not self.serial and err == errno.ECONNREFUSED and self.host is not None:
                # libmodbus 3.1.6 reports a name that does not resolve as
                # ECONNREFUSED: tell the two apart (only after a failure).
                try:
                    socket.getaddrinfo(self.host, None, type=socket.SOCK_STREAM)
                except (OSError, UnicodeError) as e:
                    hint = f"cannot resolve the host name {self.host!r} ({e})"
            raise ModbusConnectionError(
                f"cannot open {self.name}: {hint}", errno=err, port=self.name
            )
        if self.serial and lib.flock(lib.modbus_get_socket(ctx), lib.LOCK_EX | lib.LOCK_NB):
            lib.modbus_close(ctx)
            lib.modbus_free(ctx)
            raise ModbusConnectionError(
                f"cannot open {self.name}: the port is in use by another process "
                "(another pymb holds its lock)",
                errno=errno.EBUSY,
                port=self.name,
            )
        self._ctx = ctx
        self.is_open = True
        try:
            line = lib.pymb_line_new(ctx, self._framing, self._silence_us)
            if line == ffi.NULL:
                raise ModbusConnectionError(
                    f"cannot set up {self.name}: {os.strerror(ffi.errno)}",
                    errno=ffi.errno, port=self.name)
            self._line = line
            self._header = int(lib.pymb_line_header_length(line))
            lib.pymb_line_set_interrupt(line, lib.pymb_py_interrupted, ffi.NULL)
            lib.pymb_line_set_char_ns(line, self._char_ns if self._reject_early else 0)
            self._apply_timeouts()
            self._apply_rs485()
        except BaseException:
            self.close()  # a failed open leaves nothing open, nothing locked
            raise

    def set_reject_early(self, on: bool) -> None:
        """Drop reply bytes that arrive before the request can have been
        answered (its wire time plus t3.5; serial lines only)."""
        self._reject_early = on and self._char_ns > 0
        if self.is_open:
            lib.pymb_line_set_char_ns(self._line, self._char_ns if self._reject_early else 0)

    def close(self) -> None:
        """Close and free the context; safe to call twice."""
        ctx, self._ctx = self._ctx, ffi.NULL
        line, self._line = self._line, ffi.NULL
        self.is_open = False
        if line != ffi.NULL:
            lib.pymb_line_free(line)
        if ctx != ffi.NULL:
            lib.modbus_close(ctx)
            lib.modbus_free(ctx)

    def __del__(self) -> None:
        # The descriptor and, on a serial line, its lock go with the Link.
        if getattr(self, "_ctx", ffi.NULL) != ffi.NULL or getattr(
                self, "_line", ffi.NULL) != ffi.NULL:
            self.close()

    def fileno(self) -> int:
        """The file descriptor of the open line, -1 when closed."""
        return int(lib.modbus_get_socket(self._ctx)) if self.is_open else -1

    # -- settings --------------------------------------------------------------

    def set_timeouts(self, response: float, byte: float) -> None:
        """Response timeout and inter-byte timeout (0 disables it: the whole
        reply must then arrive within the response timeout)."""
        self._timeout = (response, byte)
        if self.is_open:
            self._apply_timeouts()

    def _apply_timeouts(self) -> None:
        response, byte = self._timeout
        rs, rus = divmod(max(1, round(response * 1e6)), 1_000_000)
        bs, bus = divmod(max(0, round(byte * 1e6)), 1_000_000)
        if (
            lib.modbus_set_response_timeout(self._ctx, rs, rus) == -1
            or lib.modbus_set_byte_timeout(self._ctx, bs, bus) == -1
        ):
            raise InvalidArgument(f"timeout out of range: {response!r}, {byte!r}")

    def set_rs485(self, mode: int | None, rts: int | None, rts_delay_us: int | None) -> None:
        """Serial mode (MODBUS_RTU_RS232/RS485), RTS mode and RTS delay."""
        self._rs485 = (mode, rts, rts_delay_us)
        if self.is_open:
            self._apply_rs485()

    def _apply_rs485(self) -> None:
        mode, rts, delay = self._rs485
        calls = (
            (mode, lib.modbus_rtu_set_serial_mode, "serial mode"),
            (rts, lib.modbus_rtu_set_rts, "RTS mode"),
            (delay, lib.modbus_rtu_set_rts_delay, "RTS delay"),
        )
        for value, fn, what in calls:
            if value is not None and fn(self._ctx, value) == -1:
                err = ffi.errno
                raise ModbusConnectionError(
                    f"cannot set {what} {value} on {self.name}: {os.strerror(err)} "
                    "(RS485 settings need a port whose driver supports them)",
                    errno=err,
                    port=self.name,
                )

    # -- requests --------------------------------------------------------------

    def read_registers(
        self, function: int, slave: int, address: int, count: int, dest: Any
    ) -> None:
        """Read ``count`` registers into ``dest`` (a writable uint16 buffer)."""
        # The hot path: one C call (a closed line fails in C, with EINVAL,
        # and _error tells it apart).
        if lib.pymb_read_registers(self._line, function, slave, address, count,
                                   _from_buffer("uint16_t[]", dest, True), self._fail) < 0:
            raise self._error(function, slave, address, count)

    def read_bits(self, function: int, slave: int, address: int, count: int, dest: Any) -> None:
        """Read ``count`` bits into ``dest`` (a writable byte buffer, 0/1 each)."""
        if not self.is_open:
            raise self._closed(function, slave, address, count)
        rc = lib.pymb_read_bits(
            self._line, function, slave, address, count,
            ffi.from_buffer("uint8_t[]", dest, require_writable=True), self._fail,
        )
        if rc < 0:
            raise self._error(function, slave, address, count)

    def transact(self, request: bytes, *, address: int | None = None,
                 count: int | None = None, expect: int = 0) -> bytes:
        """Send ``request`` (slave address + PDU) and return the checked reply
        PDU (function code first). Broadcast (slave 0 on a serial line)
        returns ``b""``. ``expect``: the reply PDU's length when known (0:
        from the function code, the MBAP length, or the line's silence)."""
        slave, function = request[0], request[1]
        if not self.is_open:
            raise self._closed(function, slave, address, count)
        n = lib.pymb_transact(
            self._line, request, len(request), expect, self._rsp, lib.MODBUS_MAX_ADU_LENGTH,
            self._fail,
        )
        if n < 0:
            raise self._error(function, slave, address, count)
        return bytes(ffi.buffer(self._rsp + self._header, n))

    def hub_read(self, sweep: HubSweep) -> int:
        """Run a prepared hub sweep (one C call); returns the read block mask."""
        rq = sweep.request
        if not self.is_open:
            raise self._closed(FunctionCode.READ_HOLDING_REGISTERS, rq.slave, None, None)
        if lib.pymb_hub_read(self._line, rq, self._fail) < 0:
            raise self._error(FunctionCode.READ_HOLDING_REGISTERS, rq.slave, None, None,
                              context="hub sweep")
        return int(rq.read_mask)

    def drain(self, quiet: float, limit: float) -> int:
        """Drop input until the line is quiet for ``quiet`` seconds."""
        if not self.is_open:
            return 0
        n = int(lib.pymb_drain(self._line, round(quiet * 1e6), round(limit * 1e6)))
        if n < 0:
            err = ffi.errno
            exc = _take_interrupt() if err == errno.EINTR else None
            if exc is not None:
                raise exc
            raise ModbusConnectionError(f"drain on {self.name}: {os_hint(err)}", errno=err,
                                        port=self.name)
        return n

    # -- errors ----------------------------------------------------------------

    def _closed(self, function: int, slave: int, address: int | None,
                count: int | None) -> ModbusConnectionError:
        op = _FUNCTION_NAMES.get(function, f"function 0x{function:02X}")
        return ModbusConnectionError(
            f"{op}(slave={slave}) on {self.name}: the port is not open",
            errno=errno.EBADF, slave=slave, function=function, address=address, count=count,
            port=self.name,
        )

    def _error(self, function: int, slave: int, address: int | None,
               count: int | None, context: str | None = None) -> ModbusError:
        """Turn errno (read right after the failing call) and the failure
        record into the exception to raise."""
        err = ffi.errno
        if not self.is_open:
            return self._closed(function, slave, address, count)
        if err == errno.EINTR:
            exc = _take_interrupt()
            if exc is not None:  # a signal handler raised: that is the error
                return exc  # type: ignore[return-value]
        fail = self._fail
        op = _FUNCTION_NAMES.get(function, f"function 0x{function:02X}")
        args = [f"slave={slave}"]
        if address is not None:
            args.append(f"address={address}")
        if count is not None:
            args.append(f"count={count}")
        asked = f"{context or op}({', '.join(args)}) on {self.name}"
        if (
            function in _READS
            and fail.count >= 0
            and (fail.address, fail.count) != (address, count)
        ):
            asked += f" [in the request for {fail.count} at {fail.address}]"
        got = bytes(ffi.buffer(fail.rsp, fail.rsp_len)) if fail.rsp_len > 0 else None
        received = f" (received {_hex(got)})" if got else ""
        if address is None and function in _READS and fail.count >= 0:
            address, count = fail.address, fail.count
        kw: dict[str, Any] = dict(
            slave=slave, function=function, address=address, count=count, port=self.name,
            response=got,
        )
        if err == errno.ETIMEDOUT:
            timeout = self._timeout[0]
            if got:
                return ModbusTimeout(
                    f"{asked}: the reply was incomplete after {len(got)} bytes, within "
                    f"the {timeout:g} s timeout{received}", **kw)
            return ModbusTimeout(
                f"{asked}: no reply within the {timeout:g} s timeout (the device is silent, "
                "or the address, baud rate or wiring is wrong)", **kw
            )
        code = int(lib.pymb_errno_exception(err))
        if code:
            cls = exception_class(code)
            return cls(f"{asked}: device answered exception {code:02X} ({cls.description})"
                       f"{received}", code=code, **kw)
        if err == lib.EMBBADCRC:
            return ProtocolError(f"{asked}: reply failed its CRC check{received}",
                                 reason="bad CRC", **kw)
        if err == lib.EMBBADSLAVE:
            h = fail.header if 1 <= fail.header <= len(got or b"") else 0
            who = f" {got[h - 1]}" if got and h else ""
            return ProtocolError(f"{asked}: reply came from another address{who}{received}",
                                 reason="wrong slave", **kw)
        if err == lib.EMBBADEXC:
            return ProtocolError(f"{asked}: reply is an invalid exception response{received}",
                                 reason="invalid exception", **kw)
        if err in (lib.EMBBADDATA, lib.EMBMDATA, lib.EMBUNKEXC):
            why = ffi.string(lib.pymb_frame_strerror(fail.frame)).decode() if fail.frame else (
                "malformed reply")
            return ProtocolError(f"{asked}: {why}{received}", reason=why, **kw)
        if err == errno.EINVAL:
            return InvalidArgument(f"{asked}: invalid argument", **kw)
        if err == errno.EINTR:
            return ModbusConnectionError(f"{asked}: interrupted", errno=err, **kw)
        return ModbusConnectionError(f"{asked}: {os_hint(err)}", errno=err, **kw)


def new_rtu(port: str, baudrate: int, parity: str, data_bits: int, stop_bits: int) -> Link:
    """A serial-line Link (not yet open)."""
    bits = 1 + data_bits + (0 if parity == "N" else 1) + stop_bits
    dev = port.encode()
    par = parity.encode()
    return Link(
        port,
        lambda: lib.modbus_new_rtu(dev, baudrate, par, data_bits, stop_bits),
        serial=True,
        silence=rtu_silence(baudrate),
        char_ns=int(lib.pymb_rtu_char_ns(baudrate, bits)),
    )


def new_tcp(host: str, port: int, *, rtu_framing: bool = False,
            silence: float = 0.0) -> Link:
    """A Modbus TCP Link (not yet open); ``host`` is a name or an address.
    ``rtu_framing``: RTU frames (address, PDU, CRC) on the socket instead of
    MBAP, as transparent serial servers in "raw" mode carry them; a reply of
    unknown length then ends at ``silence`` seconds of silence."""
    node = host.encode()
    service = str(port).encode()
    return Link(f"{host}:{port}", lambda: lib.modbus_new_tcp_pi(node, service), serial=False,
                host=host,
                framing=lib.PYMB_FRAMING_RTU_OVER_TCP if rtu_framing else lib.PYMB_FRAMING_TCP,
                silence=silence)


# -- decoders and the hub sweep --------------------------------------------------

HUB_REGISTERS = int(lib.PYMB_HUB_REGISTERS)
HUB_BLOCKS = int(lib.PYMB_HUB_BLOCKS)
HUB_ALL_BLOCKS = int(lib.PYMB_HUB_ALL_BLOCKS)  #: the block mask with every block set
HUB_CHANNELS = int(lib.PYMB_HUB_CHANNELS)
HUB_BITMAP_BYTES = int(lib.PYMB_HUB_BITMAP_BYTES)


def hub_decode(regs: Any, channels: int, tenths: bytes | None, wanted: bytes | None,
               read_mask: int, unsupported: int, values: Any, states: Any) -> None:
    """Decode 700 raw hub registers into ``values`` (float64) and ``states``
    (uint8), 7 x ``channels`` each, block-major (see pymb_hub_decode)."""
    rq = ffi.new("pymb_hub_request *")
    # pymb_hub_decode reads PYMB_HUB_REGISTERS registers: a shorter buffer is
    # refused here, before C could read past it.
    keep = (_from_buffer("uint16_t[]", regs), _from_buffer("double[]", values, True),
            _from_buffer("uint8_t[]", states, True),
            _NULL if tenths is None else ffi.from_buffer("uint8_t[]", tenths),
            _NULL if wanted is None else ffi.from_buffer("uint8_t[]", wanted))
    rq.regs, rq.values, rq.states, rq.humidity_tenths, rq.wanted = keep
    rq.channels = channels
    rq.read_mask = read_mask
    rq.unsupported = unsupported
    rq.out_len = len(values)
    rc = -1 if len(regs) != HUB_REGISTERS else lib.pymb_hub_decode(rq)
    if rc < 0:
        raise InvalidArgument(
            f"cannot decode {len(regs)} registers for {channels} channels: the hub block is "
            f"{HUB_REGISTERS} registers (31..730) and 1..{HUB_CHANNELS} channels"
        )


def hub_plan_all(skip_mask: int, channels: int) -> list[tuple[int, int]]:
    """The C core's plan for a full sweep: (address, count) requests."""
    spans = ffi.new("pymb_span[]", 16)
    n = lib.pymb_hub_plan_all(skip_mask, channels, spans, 16)
    if n < 0:
        raise InvalidArgument(f"cannot plan a sweep of {channels} channels")
    return [(spans[i].address, spans[i].count) for i in range(n)]


class HubSweep:
    """A prepared ``pymb_hub_request``: slave, channels, humidity units, the
    plan and the firmware knowledge, kept across sweeps of one device."""

    def __init__(self, slave: int, channels: int, tenths: bytes, busy_retries: int,
                 busy_backoff: float) -> None:
        self.request = rq = ffi.new("pymb_hub_request *")
        self._tenths = ffi.new("uint8_t[]", tenths)
        self._spans = ffi.new("pymb_span[]", HUB_REGISTERS)
        self._wanted: Any = ffi.NULL
        rq.slave = slave
        rq.channels = channels
        rq.humidity_tenths = self._tenths
        rq.options.busy_retries = busy_retries
        rq.options.busy_backoff_us = round(busy_backoff * 1e6)
        rq.spans = self._spans

    def set_plan(self, spans: list[tuple[int, int]], wanted: bytes | None) -> None:
        """The requests to make and the registers wanted (None: all asked)."""
        for i, (address, count) in enumerate(spans):
            self._spans[i].address = address
            self._spans[i].count = count
        self.request.nspans = len(spans)
        self._wanted = ffi.NULL if wanted is None else ffi.new("uint8_t[]", wanted)
        self.request.wanted = self._wanted

    @property
    def wanted(self) -> bytes | None:
        """The wanted-register bitmap of the current plan."""
        return None if self._wanted == ffi.NULL else bytes(ffi.buffer(self._wanted))

    @property
    def unsupported(self) -> int:
        """Bit mask of the blocks the firmware lacks (as far as known)."""
        return int(self.request.unsupported)

    @unsupported.setter
    def unsupported(self, mask: int) -> None:
        self.request.unsupported = mask

    def bind(self, regs: Any, values: Any, states: Any) -> tuple[Any, ...]:
        """Point the request at this reading's buffers; keep the result alive
        until the sweep returns."""
        rq = self.request
        keep = (
            ffi.from_buffer("uint16_t[]", regs, require_writable=True),
            ffi.from_buffer("double[]", values, require_writable=True),
            ffi.from_buffer("uint8_t[]", states, require_writable=True),
        )
        rq.regs, rq.values, rq.states = keep
        rq.out_len = len(values)
        return keep

    def unbind(self) -> None:
        """Forget the reading's buffers (they may be freed after the sweep)."""
        rq = self.request
        rq.regs = rq.values = rq.states = _NULL


_telemetry_local = threading.local()


def _unpacker(ctype: str) -> struct.Struct:
    """A struct.Struct reading a C struct of doubles and unsigned ints field
    by field at the offsets the compiler chose: all its fields in one call
    (attribute reads on cdata cost a call each)."""
    codes = {"double": "d", "uint32_t": "I", "uint16_t": "H", "uint8_t": "B"}
    fmt, pos = "=", 0
    for _, f in ffi.typeof(ctype).fields:
        fmt += "x" * (f.offset - pos) + codes[f.type.cname]
        pos = f.offset + ffi.sizeof(f.type)
    return struct.Struct(fmt)


_TELEMETRY = _unpacker("pymb_coolpro_telemetry")


def coolpro_telemetry(regs: Any) -> tuple[float, float, float, float, float, int, int]:
    """Decode input registers 0..7: (Vin, Iin, Vout, Iout, temperature, uptime, status)."""
    out = getattr(_telemetry_local, "out", None)
    if out is None:  # one output struct per thread, not one allocation per read
        t = ffi.new("pymb_coolpro_telemetry *")
        out = _telemetry_local.out = (t, ffi.buffer(t))
    if lib.pymb_coolpro_decode_telemetry(_from_buffer("uint16_t[]", regs), len(regs), out[0]):
        raise InvalidArgument(f"telemetry is 8 registers, got {len(regs)}")
    values: tuple[float, float, float, float, float, int, int] = _TELEMETRY.unpack_from(out[1])
    return values


def coolpro_identity(regs: Any) -> tuple[int, int, int, int, int, int]:
    """Decode input registers 100..107: (serial, hw rev, major, minor, patch, manufactured)."""
    d = ffi.new("pymb_coolpro_identity *")
    if lib.pymb_coolpro_decode_identity(ffi.from_buffer("uint16_t[]", regs), len(regs), d):
        raise InvalidArgument(f"identity is 8 registers, got {len(regs)}")
    return (int(d.serial_number), int(d.hardware_revision), int(d.firmware_major),
            int(d.firmware_minor), int(d.firmware_patch), int(d.manufactured))
