"""The :class:`Client` base every transport shares.

It checks each argument before anything is sent, splits long reads into maximal requests
filling one preallocated array, holds a lock per request and checks each reply; the
behaviour it promises is described once, in :mod:`pymb.client`.
"""

from __future__ import annotations

import struct
import threading
import warnings
from array import array
from collections.abc import Iterable, Mapping, Sequence, Set
from types import TracebackType
from typing import Any, Self

from pymb import _native
from pymb.client.checks import (
    _CLOSED_BY_PEER,
    _LINK_LOST,
    FC,
    MAX_WR_READ_REGISTERS,
    MAX_WR_WRITE_REGISTERS,
    MAX_WRITE_BITS,
    MAX_WRITE_REGISTERS,
    _coil,
    _int,
    _register_values,
    _seconds,
)
from pymb.errors import DeviceException, InvalidArgument, ModbusConnectionError
from pymb.wire import registers_from_wire

__all__ = ["Client"]


class Client:
    """What both clients share: the request methods and the life cycle.

    Use as a context manager (connect on enter, close on exit) or call
    :meth:`connect` and :meth:`close`. After the OS loses the link (an
    unplugged adapter, a reset TCP connection) the request that saw it raises
    :class:`~pymb.ModbusConnectionError`; the next request reconnects once
    by itself, and :attr:`connections` counts every successful connect. Over
    TCP, a read that finds the connection closed by the device after it
    carried a reply (some devices take one request a connection) is sent
    again on a new connection (:attr:`resends` counts those); a write never is.
    """

    _max_slave = 255
    _min_read_slave = 1
    #: a transport whose peer may close the connection after each reply (some
    #: Modbus TCP devices and gateways take one request a connection): a read
    #: that finds the connection closed after it carried a reply is sent again
    #: on a new one (never a write: the device may have done it)
    _resend_reads = False
    _served = 0  #: replies on the connection open now

    def __init__(self, link: _native.Link, *, slave: int | None, timeout: float,
                 byte_timeout: float) -> None:
        self._link = link
        self._lock = threading.Lock()
        self._slave: int | None = None
        self._timeout = 1.0
        self._byte_timeout = 0.0
        self._wanted = False  # connect() called and close() not since
        self.connections = 0
        #: of :attr:`connections`, those opened to send a read again because the
        #: peer closed the last one after its reply (the same device)
        self.resends = 0
        if slave is not None:
            self.slave = slave
        self.set_timeout(timeout, byte_timeout)

    # -- life cycle ---------------------------------------------------------------

    @property
    def port(self) -> str:
        """The serial device or ``host:port`` this client talks to."""
        return self._link.name

    @property
    def connected(self) -> bool:
        """True while the line is open."""
        return self._link.is_open

    def connect(self) -> None:
        """Open the line. Raises :class:`~pymb.ModbusConnectionError`."""
        with self._lock:
            self._open()  # a failure leaves nothing open and the client closed
            self._wanted = True

    def _open(self) -> None:
        if not self._link.is_open:
            self._link.open()
            try:
                self._opened()
            except BaseException:
                self._link.close()
                raise
            self.connections += 1
            self._served = 0

    def _opened(self) -> None:
        """After the line opens: what a transport decides from the open line."""

    def ensure_connected(self) -> bool:
        """Open the line now if the next request would open it (after a lost
        link); True when it opened here. A device that needs a pause after
        connecting (a map's ``after_connect``) calls this before its request.
        Raises :class:`~pymb.ModbusConnectionError` as that request would."""
        with self._lock:
            if self._link.is_open:
                return False
            self._reopen()
            return True

    def close(self) -> None:
        """Close the line; safe to call more than once."""
        with self._lock:
            self._wanted = False
            self._link.close()

    def __del__(self) -> None:
        # Like a file: a client dropped while open is closed (its descriptor
        # and, on a serial line, the port's lock released), with a warning.
        link = getattr(self, "_link", None)
        if link is not None and link.is_open:
            try:
                warnings.warn(f"unclosed {self!r}: call close() or use `with`",
                              ResourceWarning, stacklevel=2, source=self)
            finally:
                link.close()

    def __enter__(self) -> Self:
        self.connect()
        return self

    def __exit__(self, et: type[BaseException] | None, ev: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def __repr__(self) -> str:
        state = "open" if self.connected else "closed"
        return f"<{type(self).__name__} {self.port} slave={self._slave} {state}>"

    def fileno(self) -> int:
        """The line's file descriptor (-1 when closed)."""
        return self._link.fileno()

    # -- settings -----------------------------------------------------------------

    @property
    def slave(self) -> int | None:
        """Default slave address for requests that do not name one."""
        return self._slave

    @slave.setter
    def slave(self, value: int | None) -> None:
        self._slave = None if value is None else _int("slave", value, 0, self._max_slave)

    @property
    def timeout(self) -> float:
        """Seconds to wait for a complete reply."""
        return self._timeout

    @timeout.setter
    def timeout(self, value: float) -> None:
        self.set_timeout(value, self._byte_timeout)

    def set_timeout(self, timeout: float, byte_timeout: float = 0.0) -> None:
        """Set the reply timeout and the inter-byte timeout, in seconds.

        ``byte_timeout`` 0 (the default) means the whole reply must arrive
        within ``timeout``; a positive value also fails a reply whose bytes
        stop for that long.
        """
        t = _seconds("timeout", timeout)
        b = _seconds("byte_timeout", byte_timeout, allow_zero=True)
        with self._lock:
            self._link.set_timeouts(t, b)
            self._timeout, self._byte_timeout = t, b

    # -- checks -------------------------------------------------------------------

    def _slave_for(self, slave: int | None, *, write: bool = False) -> int:
        if slave is None:
            slave = self._slave
            if slave is None:
                raise InvalidArgument(
                    "no slave address: pass slave=N or set the client's slave"
                )
        low = 0 if write else self._min_read_slave
        return _int("slave", slave, low, self._max_slave)

    @staticmethod
    def _range(address: int, count: int, limit: int | None) -> tuple[int, int]:
        address = _int("address", address, 0, 0xFFFF)
        count = _int("count", count, 1, 0x10000 if limit is None else limit)
        if address + count > 0x10000:
            raise InvalidArgument(
                f"address {address} + count {count} runs past the last address 65535"
            )
        return address, count

    def _call(self, fn: Any, *args: Any, **kwargs: Any) -> Any:
        with self._lock:
            if not self._link.is_open:
                self._reopen()
            try:
                return fn(*args, **kwargs)
            except ModbusConnectionError as e:
                self._close_if_lost(e)
                raise

    def _reopen(self) -> None:
        """Open the line again for a request (after a loss), or say why not."""
        if not self._wanted:
            raise ModbusConnectionError(
                f"{self.port} is not connected: use `with client:` or client.connect()",
                port=self.port,
            )
        self._open()

    def _close_if_lost(self, e: ModbusConnectionError) -> None:
        """After an OS error that loses the line, close it: the next request
        opens it again (the reconnect policy; :mod:`pymb._native` only maps)."""
        if e.errno in _LINK_LOST:
            self._link.close()

    def _again(self, e: ModbusConnectionError, served: int) -> bool:
        """Whether a read that failed with ``e`` goes out again on a new
        connection: the peer closed this one after it carried ``served``
        replies (at least one; each new try carries one more, so the tries
        end)."""
        if self._resend_reads and served > 0 and e.errno in _CLOSED_BY_PEER:
            self.resends += 1
            return True
        return False

    def _read_call(self, fn: Any, *args: Any) -> Any:
        """``fn(*args)``, a read, with the lock and the reconnect policy (:meth:`_again`)."""
        with self._lock:
            while True:
                if not self._link.is_open:
                    self._reopen()
                served = self._served
                try:
                    out = fn(*args)
                except DeviceException:  # a reply too
                    self._served = served + 1
                    raise
                except ModbusConnectionError as e:
                    self._close_if_lost(e)
                    if self._again(e, served):
                        continue
                    raise
                self._served = served + 1
                return out

    # -- registers ----------------------------------------------------------------

    def read_holding_registers(self, address: int, count: int, *,
                               slave: int | None = None) -> array[int]:
        """Read ``count`` holding registers (function 0x03) from ``address``.

        Any count up to the end of the address space: requests of at most 125
        registers are made as needed. Returns an ``array('H')``."""
        address, count = self._range(address, count, None)
        out = array("H", bytes(2 * count))
        self.read_holding_registers_into(address, out, slave=slave)
        return out

    def read_input_registers(self, address: int, count: int, *,
                             slave: int | None = None) -> array[int]:
        """Read ``count`` input registers (function 0x04); see
        :meth:`read_holding_registers`."""
        address, count = self._range(address, count, None)
        out = array("H", bytes(2 * count))
        self.read_input_registers_into(address, out, slave=slave)
        return out

    def read_holding_registers_into(self, address: int, dest: Any, *,
                                    slave: int | None = None) -> None:
        """Read ``len(dest)`` holding registers into a writable uint16 buffer
        (``array('H')``, a numpy uint16 array): no allocation at all."""
        self._read_regs(FC.READ_HOLDING_REGISTERS, address, dest, slave)

    def read_input_registers_into(self, address: int, dest: Any, *,
                                  slave: int | None = None) -> None:
        """Read ``len(dest)`` input registers into a writable uint16 buffer."""
        self._read_regs(FC.READ_INPUT_REGISTERS, address, dest, slave)

    def _read_regs(self, fc: int, address: int, dest: Any, slave: int | None) -> None:
        s = self._slave_for(slave)
        try:
            view = memoryview(dest)
        except TypeError:
            raise TypeError(
                f"dest must be a writable uint16 buffer (array('H')), got {type(dest).__name__}"
            ) from None
        # Not a signed 'h' buffer either: register 40000 would read as -25536.
        problem = ("is read-only" if view.readonly else
                   "is not C-contiguous" if not view.c_contiguous else
                   f"has items of format {view.format!r}"
                   if view.itemsize != 2 or view.format.lstrip("@=") != "H" else None)
        if problem:
            raise InvalidArgument(
                "dest must be a writable, contiguous buffer of unsigned 16-bit integers "
                f"(array('H'), numpy uint16); this one {problem}")
        address, n = self._range(address, view.nbytes // 2, None)
        self._read_call(self._link.read_registers, fc, s, address, n, view.cast("B"))

    # -- low level: prepared requests, for the device facades ------------------------
    # The facades (pymb.devices) check their arguments once and repeat the same requests:
    # these calls skip the checks above and take the lock and reconnect as they do.

    def swap_response_timeout_prepared(self, timeout: float) -> float:
        """Give the line the reply timeout ``timeout`` (checked by the caller) and return
        the one it had, the byte timeout and :attr:`timeout` unchanged."""
        with self._lock:
            return float(self._link.swap_response_timeout(timeout))

    def read_registers_prepared(self, function: int, slave: int, address: int,
                                dest: Any) -> None:
        """Read ``len(dest)`` registers with ``function`` (0x03 or 0x04) into
        ``dest``, a writable ``array('H')``, with no argument checks: the
        caller has checked slave, address and count (1..125, within the
        address space) once, beforehand."""
        # _call, written out: on this path a Python frame is a measurable
        # share of a read (see the bench's CoolPro table).
        link = self._link
        with self._lock:
            if not link.is_open:
                self._reopen()
            served = self._served
            try:
                link.read_registers(function, slave, address, len(dest), dest)
            except DeviceException:  # a reply too
                self._served = served + 1
                raise
            except ModbusConnectionError as e:
                self._close_if_lost(e)
                if not self._again(e, served):
                    raise
            else:
                self._served = served + 1
                return
        self._read_call(link.read_registers, function, slave, address, len(dest), dest)

    def run_read_plan(self, plan: _native.RegisterPlan, start: int = 0) -> None:
        """Run a prepared :class:`pymb._native.RegisterPlan` from request ``start`` on, in one
        C call; on failure ``plan.failed`` says which request failed."""
        link = self._link  # _call, written out, as in read_registers_prepared
        with self._lock:
            while True:
                if not link.is_open:
                    self._reopen()
                served = self._served
                try:
                    link.read_plan(plan, start)
                except DeviceException:  # a reply too, after those before it
                    self._served = served + max(0, plan.failed - start) + 1
                    raise
                except ModbusConnectionError as e:
                    self._close_if_lost(e)
                    failed = plan.failed
                    # the rest of the plan on a new connection, if this one
                    # carried a reply before the peer closed it
                    if self._again(e, served + max(0, failed - start)):
                        start = max(start, failed)
                        continue
                    raise
                self._served = served + 1
                return

    def run_hub_sweep(self, sweep: _native.HubSweep) -> int:
        """Run a prepared sensor-hub sweep (:class:`pymb._native.HubSweep`,
        which :class:`pymb.devices.SensorHub` makes and plans) as one C call;
        returns the mask of the blocks read."""
        link = self._link
        with self._lock:
            if not link.is_open:
                self._reopen()
            try:
                return link.hub_read(sweep)
            except ModbusConnectionError as e:
                self._close_if_lost(e)
                raise

    def write_register(self, address: int, value: int, *, slave: int | None = None) -> None:
        """Write one holding register (function 0x06). The device's echo must
        match the request exactly, or :class:`~pymb.ProtocolError` is raised."""
        s = self._slave_for(slave, write=True)
        address = _int("address", address, 0, 0xFFFF)
        if isinstance(value, bool):
            raise TypeError("a register value is an integer 0..65535, not a bool")
        value = _int("value", value, 0, 0xFFFF)
        self._transact(s, FC.WRITE_SINGLE_REGISTER, struct.pack(">HH", address, value), address, 1)

    def write_registers(self, address: int, values: Sequence[int] | array[int], *,
                        slave: int | None = None) -> None:
        """Write 1 to 123 holding registers (function 0x10)."""
        s = self._slave_for(slave, write=True)
        data = self._u16_payload(values)
        n = len(data) // 2
        address, n = self._range(address, n, MAX_WRITE_REGISTERS)
        self._transact(s, FC.WRITE_MULTIPLE_REGISTERS,
                       struct.pack(">HHB", address, n, 2 * n) + data, address, n)

    def mask_write_register(self, address: int, and_mask: int, or_mask: int, *,
                            slave: int | None = None) -> None:
        """Mask write (function 0x16): register = (reg & and_mask) | (or_mask & ~and_mask)."""
        s = self._slave_for(slave, write=True)
        address = _int("address", address, 0, 0xFFFF)
        and_mask = _int("and_mask", and_mask, 0, 0xFFFF)
        or_mask = _int("or_mask", or_mask, 0, 0xFFFF)
        self._transact(s, FC.MASK_WRITE_REGISTER, struct.pack(">HHH", address, and_mask, or_mask),
                       address, 1)

    def write_read_registers(self, write_address: int, values: Sequence[int] | array[int],
                             read_address: int, read_count: int, *,
                             slave: int | None = None) -> array[int]:
        """Write 1..121 registers, then read 1..125 (function 0x17), in one request."""
        s = self._slave_for(slave)
        data = self._u16_payload(values)
        n = len(data) // 2
        write_address, n = self._range(write_address, n, MAX_WR_WRITE_REGISTERS)
        read_address, read_count = self._range(read_address, read_count, MAX_WR_READ_REGISTERS)
        pdu = self._transact(
            s, FC.WRITE_AND_READ_REGISTERS,
            struct.pack(">HHHHB", read_address, read_count, write_address, n, 2 * n) + data,
            read_address, read_count,
        )
        return registers_from_wire(pdu[2:])

    @staticmethod
    def _u16_payload(values: Sequence[int] | array[int]) -> bytes:
        return _register_values(values)

    # -- bits ---------------------------------------------------------------------

    def read_coils(self, address: int, count: int, *, slave: int | None = None) -> array[int]:
        """Read ``count`` coils (function 0x01); an ``array('B')`` of 0/1.
        Counts above 2000 are split into several requests."""
        return self._read_bits(FC.READ_COILS, address, count, slave)

    def read_discrete_inputs(self, address: int, count: int, *,
                             slave: int | None = None) -> array[int]:
        """Read ``count`` discrete inputs (function 0x02); an ``array('B')`` of 0/1."""
        return self._read_bits(FC.READ_DISCRETE_INPUTS, address, count, slave)

    def _read_bits(self, fc: int, address: int, count: int, slave: int | None) -> array[int]:
        s = self._slave_for(slave)
        address, count = self._range(address, count, None)
        out = array("B", bytes(count))
        self._read_call(self._link.read_bits, fc, s, address, count, out)
        return out

    def write_coil(self, address: int, value: bool | int, *,
                   slave: int | None = None) -> None:
        """Write one coil (function 0x05)."""
        s = self._slave_for(slave, write=True)
        address = _int("address", address, 0, 0xFFFF)
        on = _coil(value)
        self._transact(s, FC.WRITE_SINGLE_COIL,
                       struct.pack(">HH", address, 0xFF00 if on else 0), address, 1)

    def write_coils(self, address: int, values: Iterable[bool | int], *,
                    slave: int | None = None) -> None:
        """Write 1 to 1968 coils (function 0x0F)."""
        s = self._slave_for(slave, write=True)
        if isinstance(values, (str, bytes, bytearray, memoryview, Set, Mapping)):
            raise TypeError(f"coil values are a sequence of bools or 0/1, not "
                            f"{type(values).__name__}")
        try:
            bits = [_coil(v) for v in values]
        except TypeError as e:
            if "coil value" in str(e):
                raise
            raise TypeError(f"coil values must be a sequence, got {type(values).__name__}"
                            ) from None
        address, _ = self._range(address, len(bits), MAX_WRITE_BITS)
        packed = bytearray((len(bits) + 7) // 8)
        for i, b in enumerate(bits):
            if b:
                packed[i // 8] |= 1 << (i % 8)
        self._transact(s, FC.WRITE_MULTIPLE_COILS,
                       struct.pack(">HHB", address, len(bits), len(packed)) + bytes(packed),
                       address, len(bits))

    # -- the rest -----------------------------------------------------------------

    def report_slave_id(self, *, slave: int | None = None) -> bytes:
        """Report server ID (function 0x11): the device's bytes after the byte count."""
        s = self._slave_for(slave)
        return self._transact(s, FC.REPORT_SLAVE_ID, b"", None, None)[2:]

    def read_exception_status(self, *, slave: int | None = None) -> int:
        """Read exception status (function 0x07, serial line): one byte."""
        s = self._slave_for(slave)
        return self._transact(s, FC.READ_EXCEPTION_STATUS, b"", None, None)[1]

    def raw_request(self, function: int, data: bytes = b"", *,
                    slave: int | None = None, response_length: int | None = None) -> bytes:
        """Send any function code (1..127) with ``data`` and return the
        reply's data (the PDU after the function code), checked as far as
        the function is known. An exception reply raises the matching
        DeviceException.

        Over TCP the reply's length is the MBAP header's. Over RTU it is
        known from the function code for the standard functions; for any
        other (0x08, 0x2B, user-defined codes) the reply ends when the line
        falls silent for t3.5, unless ``response_length`` (the bytes of
        the reply's data, what this method returns) says how long it is.
        The CRC is checked over the whole frame either way."""
        s = self._slave_for(slave, write=True)
        function = _int("function", function, 1, 0x7F)
        if isinstance(data, (str, int)):  # bytes(3) would be three zero bytes
            raise TypeError("data must be bytes (or a sequence of integers 0..255), not "
                            f"{type(data).__name__}")
        try:
            view = memoryview(data)
        except TypeError:
            view = None
        if view is not None and view.itemsize != 1:
            raise TypeError(
                f"data must be bytes, not a buffer of {view.itemsize}-byte items (its bytes "
                "would depend on the host's byte order)")
        try:
            payload = view.tobytes() if view is not None else bytes(data)
        except ValueError:
            raise InvalidArgument("data bytes must be integers 0..255") from None
        except TypeError:
            raise TypeError(
                f"data must be bytes or a sequence of integers 0..255, got "
                f"{type(data).__name__}") from None
        if len(payload) > _native.MAX_PDU_DATA:
            raise InvalidArgument(f"data is {len(payload)} bytes; a PDU holds at most "
                                  f"{_native.MAX_PDU_DATA}")
        expect = 0
        if response_length is not None:
            expect = _int("response_length", response_length, 0, _native.MAX_PDU_DATA) + 1
        return self._transact(s, function, payload, None, None, expect)[1:]

    def _transact(self, slave: int, function: int, data: bytes, address: int | None,
                  count: int | None, expect: int = 0) -> bytes:
        request = bytes((slave, function)) + data
        pdu: bytes = self._call(self._link.transact, request, address=address, count=count,
                                expect=expect)
        return pdu

    def drain(self, quiet: float = 0.05, limit: float = 1.0) -> int:
        """Read and drop input until the line has been quiet for ``quiet``
        seconds (at most ``limit``, both 0..3600); returns the bytes dropped."""
        q = _seconds("quiet", quiet, allow_zero=True)
        lim = _seconds("limit", limit, allow_zero=True)
        with self._lock:
            try:
                return self._link.drain(q, lim)
            except ModbusConnectionError as e:
                self._close_if_lost(e)
                raise
