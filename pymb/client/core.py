"""The life cycle every client shares: opening and closing the line, its
settings, the default slave, and the call policy (one lock per request,
reconnect once after a lost link, a read sent again when the peer closed the
connection after a reply). :class:`pymb.client.base.Client` adds the
requests on top; the behaviour is described once, in :mod:`pymb.client`.
"""

from __future__ import annotations

import threading
import warnings
from collections.abc import Callable
from types import TracebackType
from typing import ParamSpec, Self, TypeVar, TypeVarTuple

from pymb._native.link import Link
from pymb.client.checks import _CLOSED_BY_PEER, _LINK_LOST, _int, _seconds
from pymb.errors import DeviceException, InvalidArgument, ModbusConnectionError

__all__ = ["ClientCore", "line_lock", "stop_waiting"]

P = ParamSpec("P")
R = TypeVar("R")
Ts = TypeVarTuple("Ts")


class ClientCore:
    """What every client shares below its requests: the life cycle and the call policy.

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
    #: replies on the connection open now (an armed plan's runs are not counted,
    #: :func:`pymb.client.base.read_plan_call`: only whether there was one is asked)
    _served = 0

    def __init__(self, link: Link, *, slave: int | None, timeout: float,
                 byte_timeout: float) -> None:
        self._link = link
        # Reentrant: a map device holds it for a whole read or write (its
        # requests and the silences between them, line_lock), and makes its
        # requests through the methods that take it for each request.
        self._lock = threading.RLock()
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
        """The serial device or ``host:port`` this client talks to (an IPv6
        address in brackets, ``[::1]:502``)."""
        return self._link.name

    @property
    def fresh_connections(self) -> int:
        """Of :attr:`connections`, those that may be to another device: not
        those opened to send a read again (:attr:`resends`), which reach the
        same device, so what it taught holds on them."""
        return self.connections - self.resends

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
        """Close the line; safe to call more than once. A request another
        thread is waiting on ends at once (within 50 ms) with
        :class:`~pymb.ModbusConnectionError`, and the line closes after it."""
        lock = self._lock
        if lock._is_owned() and self._link.close_after_wait():  # type: ignore[attr-defined]  # noqa: SLF001
            self._wanted = False  # from a signal handler in this thread's wait: closed after it
            return
        if not lock.acquire(blocking=False):
            stop_waiting(self)
            lock.acquire()
        try:
            self._wanted = False
            self._link.close()
        finally:
            lock.release()

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

    def _call(self, fn: Callable[P, R], /, *args: P.args, **kwargs: P.kwargs) -> R:
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

    def _read_call(self, fn: Callable[[*Ts], R], /, *args: *Ts) -> R:
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


def stop_waiting(client: ClientCore) -> None:
    """From any thread, without ``client``'s lock: the request waiting on its
    line ends within 50 ms with :class:`~pymb.ModbusConnectionError`, and so
    does any that waits on it until it is opened again (what a close() from
    elsewhere does first)."""
    client._link.stop()  # noqa: SLF001 - this module's


def line_lock(client: ClientCore) -> threading.RLock:
    """``client``'s lock, reentrant, which each of its requests holds: a
    caller that holds it makes several requests and the silences between
    them one turn on the line (:mod:`pymb.devices.linequiet`), whichever
    thread asks next."""
    return client._lock  # noqa: SLF001 - this module's
