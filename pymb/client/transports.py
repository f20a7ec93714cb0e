"""The clients, one a transport: :class:`RtuClient` (a serial line),
:class:`TcpClient` (Modbus TCP), :class:`RtuOverTcpClient` (RTU frames
through a raw serial server), :class:`AsciiClient` (Modbus ASCII on a serial
line) and :class:`UdpClient` (Modbus over UDP)."""

from __future__ import annotations

import operator
import os

from pymb import _native
from pymb._native.transports import new_ascii, new_rtu, new_tcp, new_udp
from pymb.client.base import Client
from pymb.client.checks import (
    _PARITIES,
    _RTS_MODES,
    _SERIAL_MODES,
    _int,
    _seconds,
)
from pymb.client.tls import MBAPS_PORT, TlsConfig
from pymb.errors import InvalidArgument
from pymb.wire import DEFAULT_BAUD, DEFAULT_PARITY, DEFAULT_TIMEOUT, bits_per_char, char_time

__all__ = ["AsciiClient", "RtuClient", "RtuOverTcpClient", "TcpClient", "UdpClient"]


def _serial(port: str, baudrate: int, parity: str, data_bits: int,
            stop_bits: int) -> tuple[int, str, int, int]:
    """A serial line's port and settings checked: (baudrate, parity, data bits, stop bits)."""
    if not isinstance(port, str) or not port:
        raise InvalidArgument(f"port must be a device path, got {port!r}")
    if (isinstance(baudrate, bool) or not hasattr(type(baudrate), "__index__")
            or operator.index(baudrate) not in _native.BAUD_RATES):
        raise InvalidArgument(
            f"baudrate {baudrate!r} is not a rate the serial driver supports; "
            f"use one of {sorted(_native.BAUD_RATES)}"
        )
    p = _PARITIES.get(str(parity).upper())
    if p is None:
        raise InvalidArgument(f"parity must be 'N', 'E' or 'O', got {parity!r}")
    return (operator.index(baudrate), p,
            _int("data_bits", data_bits, 5, 8), _int("stop_bits", stop_bits, 1, 2))


class RtuClient(Client):
    """A Modbus RTU master on a serial port (or a pseudo-terminal).

    ``port``: the device, e.g. ``/dev/ttyUSB0`` or ``/dev/serial/by-id/...``.
    ``baudrate``: one of the standard rates (9600, 19200, ... 115200, ...).
    ``parity``: ``"N"``, ``"E"`` or ``"O"``. ``slave``: default address,
    1..255 (pymb frames every request itself, so 248..255, which libmodbus
    refuses, work like any other). ``timeout``: seconds for a complete reply.

    RS485 adapters: ``serial_mode="rs485"`` turns on the kernel's RS485 mode
    (drivers that support TIOCSRS485), ``rts="up"``/``"down"`` drives RTS
    from user space around each request and ``rts_delay`` (0 to 1 second)
    waits that long around it.

    ``reject_early``: drop bytes that arrive before the request can have been
    answered (its own wire time plus t3.5 at ``baudrate``), with the rest of
    their frame: a repeater's duplicate that follows its original at once is
    then never taken as the next answer. ``None`` (default): on for a real
    serial port, off on a pseudo-terminal, which has no wire time.
    """

    def __init__(
        self,
        port: str,
        baudrate: int = DEFAULT_BAUD,
        parity: str = DEFAULT_PARITY,
        data_bits: int = 8,
        stop_bits: int = 1,
        *,
        slave: int | None = None,
        timeout: float = DEFAULT_TIMEOUT,
        byte_timeout: float = 0.0,
        serial_mode: str | None = None,
        rts: str | None = None,
        rts_delay: float | None = None,
        reject_early: bool | None = None,
    ) -> None:
        self.baudrate, self.parity, self.data_bits, self.stop_bits = line = _serial(
            port, baudrate, parity, data_bits, stop_bits)
        if reject_early is not None and not isinstance(reject_early, bool):
            raise TypeError(f"reject_early must be True, False or None, got {reject_early!r}")
        self._reject_early = reject_early
        link = new_rtu(port, *line)
        super().__init__(link, slave=slave, timeout=timeout, byte_timeout=byte_timeout)
        self.set_rs485(serial_mode=serial_mode, rts=rts, rts_delay=rts_delay)

    def _opened(self) -> None:
        # Rejecting early bytes is asked for, or on by default on a real
        # serial line; a pseudo-terminal (Linux majors 136..143) has no wire
        # time, so there nothing is early.
        on = self._reject_early
        if on is None:
            try:
                on = not 136 <= os.major(os.fstat(self._link.fileno()).st_rdev) <= 143
            except OSError:
                on = False
        self._link.set_reject_early(on)

    def set_rs485(self, *, serial_mode: str | None = None, rts: str | None = None,
                  rts_delay: float | None = None) -> None:
        """RS485 settings, applied now if open and on every connect."""
        mode = None
        if serial_mode is not None:
            if serial_mode not in _SERIAL_MODES:
                raise InvalidArgument(
                    f"serial_mode must be 'rs232' or 'rs485', got {serial_mode!r}")
            mode = _SERIAL_MODES[serial_mode]
        r = None
        if rts is not None:
            if rts not in _RTS_MODES:
                raise InvalidArgument(f"rts must be 'none', 'up' or 'down', got {rts!r}")
            r = _RTS_MODES[rts]
        delay = None
        if rts_delay is not None:
            d = _seconds("rts_delay", rts_delay, allow_zero=True)
            if d > 1.0:  # libmodbus takes microseconds in an int
                raise InvalidArgument(f"rts_delay must be 0 to 1 second, got {rts_delay!r}")
            delay = round(d * 1e6)
        with self._lock:
            self._link.set_rs485(mode, r, delay)

    def frame_time(self, nbytes: int) -> float:
        """Seconds ``nbytes`` take on this line (start, data, parity, stop bits;
        :mod:`pymb.wire`)."""
        return nbytes * char_time(self.baudrate,
                                  bits_per_char(self.parity, self.stop_bits, self.data_bits))


def _check_host(host: object, client: str) -> None:
    """``host`` is a name or an address: not empty, and without a port
    (``"10.0.0.5:502"``, the command line's spelling, is refused naming the
    call that means it)."""
    if not isinstance(host, str) or not host:
        raise InvalidArgument(f"host must be a name or an address, got {host!r}")
    name, colon, port = host.rpartition(":")
    if colon and name and ":" not in name and port.isdigit():
        raise InvalidArgument(f"host {host!r} has a port in it: the port is an argument of "
                              f"its own, {client}({name!r}, {int(port)})")


class TcpClient(Client):
    """A Modbus TCP client (also for gateways that translate Modbus TCP to
    RTU; for gateways that pass RTU frames through, see
    :class:`RtuOverTcpClient`). ``host`` is a name or an address; ``slave`` is the unit identifier,
    0..255 (many gateways route it to the RTU address).

    ``tls``: Modbus/TCP Security (a :class:`~pymb.TlsConfig`; ``port`` then
    defaults to 802): every connect makes the TLS handshake within
    ``timeout`` and checks the server's certificate; the requests, their
    checks, timeouts and reconnects are those of plain TCP. A refused
    certificate fails the connect with :class:`~pymb.TlsError`."""

    _min_read_slave = 0
    _resend_reads = True

    def __init__(self, host: str = "127.0.0.1", port: int | None = None, *,
                 slave: int | None = None, timeout: float = DEFAULT_TIMEOUT,
                 byte_timeout: float = 0.0, tls: TlsConfig | None = None) -> None:
        _check_host(host, "TcpClient")
        if tls is not None and not isinstance(tls, TlsConfig):
            raise InvalidArgument(f"tls must be a pymb.TlsConfig or None, got {tls!r}")
        if port is None:
            port = MBAPS_PORT if tls is not None else 502
        port = _int("port", port, 1, 65535)
        self.host = host
        self.tcp_port = port
        #: Modbus/TCP Security's settings (None: plain Modbus TCP)
        self.tls = tls
        session = None if tls is None else (tls.context(), tls.server_name_for(host))
        super().__init__(new_tcp(host, port, tls=session), slave=slave, timeout=timeout,
                         byte_timeout=byte_timeout)

    def attach(self, fd: int, *, tid: int | None = None) -> None:
        """Connect over a connected socket of the caller's instead of a new
        connection (a poll connection lent between polls): the client takes a
        duplicate of ``fd`` and closes only that; a lost connection is not
        opened again by the client. ``tid``: the transaction id of its first
        request (the lender's next one, so that a late reply to one of the
        lender's requests is no answer to the client's). Raises
        :class:`~pymb.ModbusConnectionError`."""
        if self.tls is not None:
            raise InvalidArgument("attach() takes a plain Modbus TCP connection")
        with self._lock:
            self._link.close()
            self._link.borrowed = True
            self._link.adopt = os.dup(fd)
            try:
                self._open()
            finally:
                if self._link.adopt is not None:  # not taken: open() failed before it
                    os.close(self._link.adopt)
                    self._link.adopt = None
            self._wanted = True
            if tid is not None:
                self._link.next_tid = tid

    @property
    def next_tid(self) -> int | None:
        """The transaction id of the client's next request on its open
        connection (None while it is closed)."""
        with self._lock:
            return self._link.next_tid


class RtuOverTcpClient(Client):
    """Modbus RTU frames (address, PDU, CRC) over a TCP socket: what
    transparent serial servers and Ethernet gateways in "raw" mode carry
    (libmodbus has no such transport). Every check of :class:`RtuClient`
    applies (CRC, address, function, length, echo); replies of function codes
    whose length only the line tells end after ``frame_silence`` seconds of
    silence (default 20 ms: a gateway's TCP segments are not a serial line's
    character timing). ``slave`` is the RTU address, 1..255 (0: broadcast,
    writes only)."""

    def __init__(self, host: str = "127.0.0.1", port: int = 502, *,
                 slave: int | None = None, timeout: float = DEFAULT_TIMEOUT,
                 byte_timeout: float = 0.0, frame_silence: float = 0.02) -> None:
        _check_host(host, "RtuOverTcpClient")
        port = _int("port", port, 1, 65535)
        silence = _seconds("frame_silence", frame_silence)
        if silence > 1.0:
            raise InvalidArgument(f"frame_silence must be up to 1 second, got {frame_silence!r}")
        self.host = host
        self.tcp_port = port
        super().__init__(new_tcp(host, port, rtu_framing=True, silence=silence),
                         slave=slave, timeout=timeout, byte_timeout=byte_timeout)


class AsciiClient(Client):
    """A Modbus ASCII master on a serial port ([MB-SL] 2.5.2): each frame is
    ``:``, the address, PDU and LRC as two hexadecimal characters a byte,
    then CR LF. The specification's line is 7 data bits, even parity
    (``data_bits=7, parity="E"``); the defaults are :class:`RtuClient`'s.

    ``timeout``: seconds for a complete reply. ``byte_timeout``: the
    inter-character timeout, the longest gap inside a frame (0, the default:
    one second, as the specification says); a longer gap drops the frame
    begun. Bad LRC, another address, a wrong length or echo fail as on RTU;
    after a failure the line waits for silence before the next request to
    that address, so a late reply is never taken as a later answer. Address
    0 broadcasts (writes only).
    """

    def __init__(
        self,
        port: str,
        baudrate: int = DEFAULT_BAUD,
        parity: str = DEFAULT_PARITY,
        data_bits: int = 8,
        stop_bits: int = 1,
        *,
        slave: int | None = None,
        timeout: float = DEFAULT_TIMEOUT,
        byte_timeout: float = 0.0,
    ) -> None:
        self.baudrate, self.parity, self.data_bits, self.stop_bits = line = _serial(
            port, baudrate, parity, data_bits, stop_bits)
        super().__init__(new_ascii(port, *line), slave=slave, timeout=timeout,
                         byte_timeout=byte_timeout)

    def frame_time(self, nbytes: int) -> float:
        """Seconds a frame of ``nbytes`` bytes (address, PDU) takes on this
        line: ``:``, two characters a byte and the LRC's two, CR LF."""
        return (1 + 2 * (nbytes + 1) + 2) * char_time(
            self.baudrate, bits_per_char(self.parity, self.stop_bits, self.data_bits))


class UdpClient(Client):
    """Modbus over UDP: one MBAP frame ([MB-TCP] 3.1.3) a datagram, on a
    socket pymb opens. ``host`` is a name or an address; ``slave`` the unit
    identifier, 0..255. A request unanswered within ``timeout`` is sent
    again, ``retries`` times (0..10), with the same transaction id; a reply
    to an older request or from another unit, and any datagram that is not
    one whole Modbus frame, is dropped, never taken as the answer."""

    _min_read_slave = 0

    def __init__(self, host: str = "127.0.0.1", port: int = 502, *,
                 slave: int | None = None, timeout: float = DEFAULT_TIMEOUT,
                 retries: int = 2) -> None:
        _check_host(host, "UdpClient")
        port = _int("port", port, 1, 65535)
        retries = _int("retries", retries, 0, 10)
        self.host = host
        self.udp_port = port
        self.retries = retries
        link = new_udp(host, port)
        link.set_retries(retries)
        super().__init__(link, slave=slave, timeout=timeout, byte_timeout=0.0)
