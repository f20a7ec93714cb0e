"""The :class:`Client` base every transport shares.

It checks each argument before anything is sent, splits long reads into maximal requests
filling one preallocated array, holds a lock per request and checks each reply; the
behaviour it promises is described once, in :mod:`pymb.client`.
"""

from __future__ import annotations

import struct
from array import array
from collections.abc import Callable, Iterable, Sequence
from typing import TYPE_CHECKING

from pymb import _native
from pymb._native.link import Link, RegisterPlan
from pymb._native.link import _plan_go as plan_go
from pymb._native.link import _plan_run as plan_run
from pymb.client.checks import (
    FC,
    MAX_WR_READ_REGISTERS,
    MAX_WR_WRITE_REGISTERS,
    MAX_WRITE_BITS,
    MAX_WRITE_REGISTERS,
    _coil,
    _coil_payload,
    _int,
    _pdu_data,
    _range,
    _register_values,
    _u16_dest,
)
from pymb.client.core import ClientCore
from pymb.errors import DeviceException, ModbusConnectionError, ModbusError
from pymb.wire import registers_from_wire

if TYPE_CHECKING:
    from typing_extensions import Buffer

__all__ = ["Client", "armed_failed", "line_of", "plan_go", "read_plan_call",
           "run_read_plan_held"]


class Client(ClientCore):
    """What both clients share: the request methods on top of the life cycle
    and the call policy (:class:`~pymb.client.core.ClientCore`)."""

    # -- registers ----------------------------------------------------------------

    def read_holding_registers(self, address: int, count: int, *,
                               slave: int | None = None) -> array[int]:
        """Read ``count`` holding registers (function 0x03) from ``address``.

        Any count up to the end of the address space: requests of at most 125
        registers are made as needed. Returns an ``array('H')``."""
        address, count = _range(address, count, None)
        out = array("H", bytes(2 * count))
        self.read_holding_registers_into(address, out, slave=slave)
        return out

    def read_input_registers(self, address: int, count: int, *,
                             slave: int | None = None) -> array[int]:
        """Read ``count`` input registers (function 0x04); see
        :meth:`read_holding_registers`."""
        address, count = _range(address, count, None)
        out = array("H", bytes(2 * count))
        self.read_input_registers_into(address, out, slave=slave)
        return out

    def read_holding_registers_into(self, address: int, dest: Buffer, *,
                                    slave: int | None = None) -> None:
        """Read ``len(dest)`` holding registers into a writable uint16 buffer
        (``array('H')``, a numpy uint16 array): no allocation at all."""
        self._read_regs(FC.READ_HOLDING_REGISTERS, address, dest, slave)

    def read_input_registers_into(self, address: int, dest: Buffer, *,
                                  slave: int | None = None) -> None:
        """Read ``len(dest)`` input registers into a writable uint16 buffer."""
        self._read_regs(FC.READ_INPUT_REGISTERS, address, dest, slave)

    def _read_regs(self, fc: int, address: int, dest: Buffer, slave: int | None) -> None:
        s = self._slave_for(slave)
        view = _u16_dest(dest)
        address, n = _range(address, view.nbytes // 2, None)
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
                                dest: array[int] | memoryview) -> None:
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

    def run_read_plan(self, plan: RegisterPlan, start: int = 0,
                      on: int | None = None) -> bool:
        """Run a prepared :class:`pymb._native.link.RegisterPlan` from request ``start`` on, in one
        C call; on failure ``plan.failed`` says which request failed. ``on``: only
        while the line is open on that connection (:attr:`fresh_connections`
        says which): False, nothing sent, when it is closed or another."""
        lock = self._lock  # acquired and released, not a with block: a poller's hot path
        lock.acquire()
        try:
            return run_read_plan_held(self, plan, start, on)
        finally:
            lock.release()

    def _run_plan(self, plan: RegisterPlan, start: int) -> None:
        """:meth:`run_read_plan`'s run from ``start``, the lock held: the line
        opened again if it was lost, and the read sent again as
        :meth:`_plan_failed` says."""
        link = self._link
        while True:
            if not link.is_open:
                self._reopen()
            served = self._served
            try:
                link.read_plan(plan, start)
            except ModbusError as e:
                start = self._plan_failed(e, plan, start, served)
                continue
            self._served = served + 1
            return

    def _plan_failed(self, e: ModbusError, plan: RegisterPlan, start: int, served: int) -> int:
        """A run of ``plan`` from ``start`` failed with ``e`` at ``plan.failed``
        (``served`` replies on the connection before it): raise ``e``, or say
        where the read goes on, on a new connection, when the peer closed
        this one after it carried a reply."""
        if isinstance(e, DeviceException):  # a reply too, after those before it
            self._served = served + max(0, plan.failed - start) + 1
        elif isinstance(e, ModbusConnectionError):
            self._close_if_lost(e)
            failed = plan.failed
            if self._again(e, served + max(0, failed - start)):
                return max(start, failed)
        raise e

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
        data = _register_values(values)
        n = len(data) // 2
        address, n = _range(address, n, MAX_WRITE_REGISTERS)
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
        data = _register_values(values)
        n = len(data) // 2
        write_address, n = _range(write_address, n, MAX_WR_WRITE_REGISTERS)
        read_address, read_count = _range(read_address, read_count, MAX_WR_READ_REGISTERS)
        pdu = self._transact(
            s, FC.WRITE_AND_READ_REGISTERS,
            struct.pack(">HHHHB", read_address, read_count, write_address, n, 2 * n) + data,
            read_address, read_count,
        )
        return registers_from_wire(pdu[2:])

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
        address, count = _range(address, count, None)
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
        n, packed = _coil_payload(values)
        address, _ = _range(address, n, MAX_WRITE_BITS)
        self._transact(s, FC.WRITE_MULTIPLE_COILS,
                       struct.pack(">HHB", address, n, len(packed)) + packed, address, n)

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
        payload = _pdu_data(data)
        expect = 0
        if response_length is not None:
            expect = _int("response_length", response_length, 0, _native.MAX_PDU_DATA) + 1
        return self._transact(s, function, payload, None, None, expect)[1:]


def run_read_plan_held(client: Client, plan: RegisterPlan, start: int = 0,
                       on: int | None = None) -> bool:
    """:meth:`Client.run_read_plan` for a caller that holds the client's lock
    (:func:`~pymb.client.core.line_lock`: a map device's read): the same
    run, the same errors, without taking the lock again."""
    link = client._link  # noqa: SLF001 - this module's
    if on is not None and (not link.is_open or client.connections - client.resends != on):
        return False
    # A poller's steady state: the line open and holding the plan's reply
    # timeout, Link.read_plan's C call made here (a frame less).
    if link.is_open and plan.hold is link._held:  # noqa: SLF001 - read_plan's
        served = client._served  # noqa: SLF001 - this module's
        if plan_run(link._line, plan.c, start, link._fail) < 0:  # noqa: SLF001 - read_plan's
            client._run_plan(plan, client._plan_failed(  # noqa: SLF001 - this module's
                link.plan_error(plan, start), plan, start, served))
            return True
        client._served = served + 1  # noqa: SLF001 - this module's
        return True
    client._run_plan(plan, start)  # noqa: SLF001 - this module's
    return True


def read_plan_call(client: Client, plan: RegisterPlan) -> Callable[[int | None], bool]:
    """``run_read_plan_held(client, plan, 0, on)`` as a call of ``on`` alone,
    made ready for a caller that runs ``plan`` over and over (a device's
    steady read): the same run and errors. A run on ``on``'s connection that
    got its reply arms ``plan`` (:attr:`RegisterPlan.armed
    <pymb._native.link.RegisterPlan.armed>`): while it is armed at the line's
    :attr:`~pymb._native.link.Link.era`, a run is its one C call of one
    argument (``plan_go(plan.c)``, the plan's record holding the line it runs
    on), which a caller holding the lock may also make itself, and
    :func:`armed_failed` after it when it fails."""
    link, c = client._link, plan.c  # noqa: SLF001 - this module's
    armed_on = -1  # the connection the plan was armed on (the line's, as long as it is armed)

    def run(on: int | None) -> bool:
        nonlocal armed_on
        if plan.armed == link.era and on == armed_on:
            if plan_go(c) < 0:
                armed_failed(client, plan)
            return True
        if not run_read_plan_held(client, plan, 0, on):
            return False
        # Armed once the line carried a reply on the caller's connection, the
        # context holding the plan's timeout: the armed run then counts no
        # reply (_served is only ever asked whether there was one).
        if on is not None and link.is_open and plan.hold is link._held and (  # noqa: SLF001
                client.connections - client.resends == on and client._served > 0):  # noqa: SLF001
            c.line, c.fail = link._line, link._fail  # noqa: SLF001 - read_plan's
            plan.armed, armed_on = link.era, on
        return True
    return run


def armed_failed(client: Client, plan: RegisterPlan) -> None:
    """After the C call of ``plan``, armed (:func:`read_plan_call`), failed:
    its error raised, or the read sent again on a new connection as
    :func:`run_read_plan_held` does (the peer closed the one that carried
    its replies)."""
    client._run_plan(plan, client._plan_failed(  # noqa: SLF001 - this module's
        client._link.plan_error(plan, 0), plan, 0, client._served))  # noqa: SLF001


def line_of(client: Client) -> Link:
    """The line ``client``'s requests go over: a plan armed at its
    :attr:`~Link.era` (:func:`read_plan_call`) runs with its C call alone."""
    return client._link  # noqa: SLF001 - this module's
