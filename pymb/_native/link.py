"""A line: one libmodbus context and its pymb_line (pymb_line_new), the
interrupt hook that lets Python's signal handlers stop a wait, and the
requests. What a failure means in words is :func:`pymb.errors.request_error`'s.
"""

from __future__ import annotations

import errno
import os
import socket
import ssl
from typing import Any

from pymb._native.interrupt import LineStop, in_line_wait, take_interrupt
from pymb._native.plan import RegisterPlan, seconds_us
from pymb._native.tls import TlsSession, take_raised, tls_words
from pymb._pymb_cffi import ffi, lib
from pymb.errors import (
    InvalidArgument,
    ModbusConnectionError,
    ModbusError,
    TlsError,
    closed_error,
    os_hint,
    request_error,
    stopped_error,
)

__all__ = ["Link", "RegisterPlan"]

_FD_SETSIZE = int(lib.FD_SETSIZE)  # select()'s limit, which libmodbus's TCP code is bound by
_from_buffer = ffi.from_buffer
_plan_run = lib.pymbi_plan_run  # the hot path's C call, looked up once
_plan_go = lib.pymbi_plan_go  # ... and a steady poller's, of one argument


class Link:
    """One libmodbus context: a serial line or a TCP connection.

    Not thread-safe by itself; the clients in :mod:`pymb.client` hold a lock
    around every call.
    """

    def __init__(self, name: str, factory: Any, *, serial: bool,
                 framing: int | None = None, silence: float = 0.0, char_ns: int = 0,
                 host: str | None = None, service: str | None = None,
                 tls: tuple[ssl.SSLContext, str | None] | None = None) -> None:
        self.name = name
        #: TLS under the line: (the client's context, the server name to check)
        self.tls = tls
        self._session: TlsSession | None = None
        self.host = host  # TCP: the host name or address as given
        #: where a transport that opens its own socket (UDP) connects
        self._node = host.encode() if host is not None and service is not None else ffi.NULL
        self._service = service.encode() if service is not None else ffi.NULL
        self._retries = 0
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
        self._timeout_us = (1, 0)  # the response timeout as libmodbus takes it (s, us)
        #: a plan's response timeout the context holds instead of the line's own (None: its
        #: own): left there for the next run of such a plan, put back before any other request
        self._held: tuple[int, int] | None = None
        #: counts the changes of the line and of the reply timeout its context
        #: holds: a plan armed at this count (:attr:`RegisterPlan.armed`) runs
        #: with its C call alone
        self.era = 0
        self._rs485: tuple[int | None, int | None, int | None] = (None, None, None)
        self.adopt: int | None = None  #: a lent socket the next open() takes (TCP)
        self._stop = LineStop()  #: what ends a wait from outside (:meth:`stop`, signals)
        self._close_pending = False  #: close once the C call returns (:meth:`close_after_wait`)
        self.borrowed = False  #: lent sockets only: never a connection of its own

    # -- life cycle ------------------------------------------------------------

    def open(self) -> None:
        """Create the context, connect, lock the port, apply the settings."""
        if self.is_open:
            return
        if not self.serial and self._service == ffi.NULL:
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
        adopted, self.adopt = self.adopt, None
        if self.borrowed and (adopted is None or lib.modbus_set_socket(ctx, adopted)):
            lib.modbus_free(ctx)
            raise ModbusConnectionError(f"{self.name}: the borrowed connection is closed",
                                        errno=errno.ENOTCONN, port=self.name)
        # A borrowed socket is open already: pymb_line_connect then does nothing.
        # A TCP connect waits as long as a reply may (libmodbus's own 0.5 s else).
        lib.modbus_set_response_timeout(ctx, *self._timeout_us)
        line = lib.pymb_line_new(ctx, self._framing, self._silence_us)
        if line == ffi.NULL:
            err = ffi.errno
            lib.modbus_free(ctx)
            raise ModbusConnectionError(f"cannot set up {self.name}: {os.strerror(err)}",
                                        errno=err, port=self.name)
        if lib.pymb_line_connect(line, self._node, self._service) == -1:
            err = ffi.errno
            lib.pymb_line_free(line)
            lib.modbus_free(ctx)
            hint = os_hint(err)
            if not self.serial and err in (errno.ECONNREFUSED, errno.EHOSTUNREACH) \
                    and self.host is not None:
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
            lib.pymb_line_close(line)
            lib.pymb_line_free(line)
            lib.modbus_free(ctx)
            raise ModbusConnectionError(
                f"cannot open {self.name}: the port is in use by another process "
                "(another pymb holds its lock)",
                errno=errno.EBUSY,
                port=self.name,
            )
        self._ctx = ctx
        self._line = line
        self.is_open = True
        try:
            self._header = int(lib.pymb_line_header_length(line))
            lib.pymb_line_set_retries(line, self._retries)
            self._stop.arm(line)
            lib.pymb_line_set_char_ns(line, self._char_ns if self._reject_early else 0)
            self._apply_timeouts()
            self._apply_rs485()
            if self.tls is not None:
                self._start_tls(*self.tls)
        except BaseException:
            self.close()  # a failed open leaves nothing open, nothing locked
            raise

    def _start_tls(self, context: ssl.SSLContext, server_name: str | None) -> None:
        """The TLS handshake on the connected socket, within the response
        timeout; then the line's I/O goes through it."""
        fd = int(lib.modbus_get_socket(self._ctx))
        os.set_blocking(fd, False)
        session = TlsSession(context, server_name, fd)
        session.write_timeout = self._timeout[0]
        try:
            session.handshake(self._timeout[0])
        except (ssl.SSLError, TimeoutError, OSError) as e:
            session.release()
            err = e.errno if isinstance(e, OSError) and not isinstance(
                e, ssl.SSLError) and e.errno else errno.EPROTO
            raise TlsError(f"cannot open {self.name}: {tls_words(e, context)}", errno=err,
                           port=self.name) from None
        if lib.pymb_line_set_io(self._line, session.io) < 0:
            session.release()
            raise ModbusConnectionError(f"cannot set up {self.name}: TLS I/O refused",
                                        errno=errno.EINVAL, port=self.name)
        self._session = session

    def set_reject_early(self, on: bool) -> None:
        """Drop reply bytes that arrive before the request can have been
        answered (its wire time plus t3.5; serial lines only)."""
        self._reject_early = on and self._char_ns > 0
        if self.is_open:
            lib.pymb_line_set_char_ns(self._line, self._char_ns if self._reject_early else 0)

    @property
    def next_tid(self) -> int | None:
        """TCP, UDP: the transaction id the next request gets (None when closed)."""
        return int(lib.pymbi_line_tid(self._line)) if self.is_open else None

    @next_tid.setter
    def next_tid(self, tid: int | None) -> None:
        if self.is_open and tid is not None:
            lib.pymbi_line_set_tid(self._line, tid & 0xFFFF)

    def set_retries(self, retries: int) -> None:
        """How many times an unanswered request is sent again (UDP)."""
        self._retries = retries
        if self.is_open:
            lib.pymb_line_set_retries(self._line, retries)

    def close(self) -> None:
        """Close the line and free the context; safe to call twice."""
        ctx, self._ctx = self._ctx, ffi.NULL
        line, self._line = self._line, ffi.NULL
        session, self._session = self._session, None
        self.is_open = False
        self._close_pending = False
        self._held = None
        self.era += 1
        if session is not None:
            session.close()  # close_notify while the socket is open
        if ctx != ffi.NULL and self.borrowed and lib.modbus_get_socket(ctx) >= 0:
            # only our descriptor (libmodbus would shut the connection down)
            os.close(lib.modbus_get_socket(ctx))
            lib.modbus_set_socket(ctx, -1)
        if line != ffi.NULL:
            lib.pymb_line_close(line)
            lib.pymb_line_free(line)
        if session is not None:
            session.release()
        if ctx != ffi.NULL and line == ffi.NULL:
            lib.modbus_close(ctx)
        if ctx != ffi.NULL:
            lib.modbus_free(ctx)

    def stop(self) -> None:
        """From any thread, without the client's lock: the request waiting on this line
        ends within 50 ms (``PYMB_INTERRUPT_SLICE_US``) with :func:`stopped_error`, and
        none is sent until the line opens again. The flag is the Link's own memory:
        safe while another thread closes the line."""
        self._stop.stop()

    def close_after_wait(self) -> bool:
        """From a signal handler inside this thread's wait on the line (the
        C call on the stack: the line must not be freed under it): stop the
        wait, close once the call has returned, and True. Elsewhere False."""
        self._close_pending = self._close_pending or in_line_wait()
        if self._close_pending:
            self._stop.stop()
        return self._close_pending

    def _close_if_pending(self) -> None:
        if self._close_pending:  # close() from a signal handler in the wait: safe now
            self.close()

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
        self._timeout_us = seconds_us(response)
        if self._session is not None:
            self._session.write_timeout = response
        if self.is_open:
            self._apply_timeouts()

    def swap_response_timeout(self, response: float) -> float:
        """Set the response timeout alone (one C call; the byte timeout
        stays) and return the one it replaces."""
        before, byte = self._timeout
        self._timeout = (response, byte)
        self._timeout_us = seconds_us(response)
        if self.is_open:
            lib.modbus_set_response_timeout(self._ctx, *self._timeout_us)
            self._held = None
            self.era += 1
        return before

    def _apply_timeouts(self) -> None:
        response, byte = self._timeout
        rs, rus = self._timeout_us
        bs, bus = divmod(max(0, round(byte * 1e6)), 1_000_000)
        if (
            lib.modbus_set_response_timeout(self._ctx, rs, rus) == -1
            or lib.modbus_set_byte_timeout(self._ctx, bs, bus) == -1
        ):
            raise InvalidArgument(f"timeout out of range: {response!r}, {byte!r}")
        self._held = None
        self.era += 1

    def _own_timeout(self) -> None:
        """Give the context the line's own response timeout back (after a plan's)."""
        lib.modbus_set_response_timeout(self._ctx, *self._timeout_us)
        self._held = None
        self.era += 1

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
        if self._held is not None:
            self._own_timeout()
        if lib.pymb_read_registers(self._line, function, slave, address, count,
                                   _from_buffer("uint16_t[]", dest, True), self._fail) < 0:
            raise self._error(function, slave, address, count)

    def read_bits(self, function: int, slave: int, address: int, count: int, dest: Any) -> None:
        """Read ``count`` bits into ``dest`` (a writable byte buffer, 0/1 each)."""
        if not self.is_open:
            raise self._closed(function, slave, address, count)
        if self._held is not None:
            self._own_timeout()
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
        if self._stop.stopped:  # a close() is under way (another thread, a handler): not sent
            self._close_if_pending()
            raise stopped_error(function, slave, address, count, self.name, sent=False)
        if self._held is not None:
            self._own_timeout()
        n = lib.pymb_transact(
            self._line, request, len(request), expect, self._rsp, lib.MODBUS_MAX_ADU_LENGTH,
            self._fail,
        )
        if n < 0:
            raise self._error(function, slave, address, count)
        return bytes(ffi.buffer(self._rsp + self._header, n))

    def read_plan(self, plan: RegisterPlan, start: int = 0) -> None:
        """Run ``plan``'s requests from ``start`` on, in one C call; on
        failure ``plan.failed`` is the index of the request that failed.
        The plan's reply timeout stays on the line until a request of another
        timeout: a poller running the same plan sets it once."""
        hold = plan.hold
        if hold is not self._held:
            if hold is None:
                self._own_timeout()
            elif self.is_open:
                lib.modbus_set_response_timeout(self._ctx, *hold)
                self._held = hold
                self.era += 1
        if _plan_run(self._line, plan.c, start, self._fail) < 0:
            raise self.plan_error(plan, start)

    def plan_error(self, plan: RegisterPlan, start: int) -> ModbusError:
        """The error of a run of ``plan`` from ``start`` that failed just now
        (errno and the failure record as it left them), ``plan.failed`` set."""
        k = plan.failed = start + int(plan.c.done)
        function, slave, address, count, _ = plan.requests[min(k, plan.n - 1)]
        return self._error(function, slave, address, count)

    def drain(self, quiet: float, limit: float) -> int:
        """Drop input until the line is quiet for ``quiet`` seconds."""
        if not self.is_open:
            return 0
        if self._held is not None:
            self._own_timeout()
        n = int(lib.pymb_drain(self._line, round(quiet * 1e6), round(limit * 1e6)))
        if n < 0:
            err = ffi.errno
            exc = (take_interrupt() or take_raised()) if err == errno.EINTR else None
            if exc is None and err == errno.EINTR and self._stop.stopped:
                exc = ModbusConnectionError(f"drain on {self.name}: the client was closed while "
                                            "it waited", errno=errno.ECANCELED, port=self.name)
            self._close_if_pending()
            raise exc or ModbusConnectionError(f"drain on {self.name}: {os_hint(err)}",
                                               errno=err, port=self.name)
        return n

    # -- errors ----------------------------------------------------------------

    def _closed(self, function: int, slave: int, address: int | None,
                count: int | None) -> ModbusConnectionError:
        return closed_error(function, slave, address, count, self.name)

    def _error(self, function: int, slave: int, address: int | None,
               count: int | None, context: str | None = None) -> ModbusError:
        """Turn errno (read right after the failing call) and the failure
        record into the exception to raise (and close the line if a signal
        handler asked for it in the wait)."""
        exc = self._failure(function, slave, address, count, context)
        self._close_if_pending()
        return exc

    def _failure(self, function: int, slave: int, address: int | None,
                 count: int | None, context: str | None) -> ModbusError:
        err = ffi.errno
        if not self.is_open:
            return self._closed(function, slave, address, count)
        if err == errno.EINTR:
            exc = take_interrupt() or take_raised()
            if exc is not None:  # a signal handler raised: that is the error
                return exc  # type: ignore[return-value]
            if self._stop.stopped:  # stop(): a close() in another thread
                return stopped_error(function, slave, address, count, self.name)
        fail = self._fail
        tls = None
        session = self._session
        if session is not None:
            if session.error is not None:
                tls, session.error = session.error, None
            elif not session.received and err in (errno.ECONNRESET, errno.EPIPE):
                tls = ("the server closed the connection after the TLS handshake, before any "
                       "reply (does it refuse this client or its certificate?)")
        frame = ffi.string(lib.pymb_frame_strerror(fail.frame)).decode() if fail.frame else None
        return request_error(
            err, function=function, slave=slave, address=address, count=count, port=self.name,
            timeout=self._timeout[0], failed=(fail.address, fail.count), sends=self._retries + 1,
            response=bytes(ffi.buffer(fail.rsp, fail.rsp_len)) if fail.rsp_len > 0 else None,
            header=fail.header, frame=frame, context=context, tls=tls,
            dropped=fail.frame < lib.PYMB_FRAME_INCOMPLETE,  # (a frame cut short: -1)
            checksum="LRC" if self._framing == lib.PYMB_FRAMING_ASCII else "CRC")

