"""asyncio clients: :class:`AsyncRtuClient`, :class:`AsyncTcpClient`,
:class:`AsyncRtuOverTcpClient`, :class:`AsyncAsciiClient` and
:class:`AsyncUdpClient`.

Each is a blocking client of :mod:`pymb.client` (its ``blocking`` twin)
driven by one worker thread that owns the line: every request runs there
in the C core, which keeps the wire timing (t3.5, the quiet window after a
failure), and the event loop only waits for the result. Methods, arguments,
results and exceptions are the blocking client's; the request methods are
coroutines.

Order: the requests of one client run one at a time in the order they were
awaited (concurrent awaits queue, they never interleave on the wire);
requests of different clients run at the same time on their own threads
(the C core releases the GIL).

Cancellation: a request whose await is cancelled before its turn is never
sent. One already on the wire completes on the worker (within the client's
timeout) and its reply, or its failure, is dropped; the next request starts
only after it, so no later request can take its reply, and after a timeout
the line's quiet-window rule holds the next one back until the line has been
silent. A cancelled ``read_*_into`` (or a sweep ``into`` a reading) may
still fill its buffer until then.

Shutdown: :meth:`AsyncClient.close` closes the line and ends the worker;
the request on the line ends at once and those queued before the close
never go out (their awaits raise :class:`~pymb.ModbusConnectionError`).
An open client also ends so when its event loop shuts down (``asyncio.run``,
``asyncio.Runner``): a small guard task on the loop closes the line when the
loop cancels its tasks. Nothing outlives it: no thread, no descriptor, no
port lock.
"""

from __future__ import annotations

import asyncio
import contextlib
import warnings
from collections.abc import Callable
from types import TracebackType
from typing import ParamSpec, Self, TypeVar

from pymb.aio._mirror import Forward, Mirror, Mirrored
from pymb.aio._worker import LineWorker
from pymb.client import (
    AsciiClient,
    Client,
    RtuClient,
    RtuOverTcpClient,
    TcpClient,
    TlsConfig,
    UdpClient,
)
from pymb.errors import InvalidArgument
from pymb.wire import DEFAULT_BAUD, DEFAULT_PARITY, DEFAULT_TIMEOUT

__all__ = ["AsyncAsciiClient", "AsyncClient", "AsyncRtuClient", "AsyncRtuOverTcpClient",
           "AsyncTcpClient", "AsyncUdpClient"]

P = ParamSpec("P")
R = TypeVar("R")


async def _guard(line: LineWorker, closed: asyncio.Future[None]) -> None:
    """Wait for the client's close(); when the loop cancels every task at
    its end instead, close the line (after the request on it) and end the
    worker."""
    try:
        await closed
    except asyncio.CancelledError:
        line.cut()  # the request on the wire: its await was cancelled too
        await line.submit(line.blocking.close)
        line.join_ended()
        raise


def _watch(line: LineWorker, closed: asyncio.Future[None], name: str) -> asyncio.Task[None]:
    """The guard task of an open client on the running loop. A loop closed
    by hand with it pending (no asyncio.run, its tasks never cancelled) drops
    it in silence: the client is closed when it is dropped, or by the next
    loop it is used in."""
    task = asyncio.get_running_loop().create_task(_guard(line, closed), name=name)
    # asyncio's own flag (its run_until_complete and gather clear it too):
    # no "Task was destroyed but it is pending!" for a guard that never ran.
    task._log_destroy_pending = False  # type: ignore[attr-defined]  # noqa: SLF001
    return task


def _release(closed: asyncio.Future[None]) -> None:
    """Let the guard waiting on ``closed`` end, from any thread; a guard of
    a loop closed meanwhile went with it."""
    loop = closed.get_loop()
    try:
        running = asyncio.get_running_loop()
    except RuntimeError:
        running = None
    if running is not loop:
        with contextlib.suppress(RuntimeError):  # (its loop may be closed)
            loop.call_soon_threadsafe(_release, closed)
    elif not closed.done():
        closed.set_result(None)


class AsyncClient(Mirrored):
    """What the three async clients share: the life cycle, the settings and
    the request methods, each the blocking :class:`pymb.Client`'s as a
    coroutine. Use ``async with`` (connect on enter, close on exit) or
    ``await connect()`` and ``await close()``."""

    blocking: Client  #: the blocking client this one drives on its worker

    def __init__(self, blocking: Client) -> None:
        self.blocking = blocking
        self._worker = LineWorker(blocking, f"pymb-aio {blocking.port}")
        self._guard: asyncio.Task[None] | None = None
        self._closed: asyncio.Future[None] | None = None

    # -- life cycle -----------------------------------------------------------------

    port = Forward[str]("The serial device or ``host:port`` this client talks to.")

    connected = Forward[bool]("True while the line is open.")

    connections = Forward[int]("Successful connects so far (the blocking client's count).")

    resends = Forward[int](
        """Of :attr:`connections`, those opened to send a read again after the
        peer closed the last one behind its reply (the blocking client's count).""")

    fresh_connections = Forward[int](
        """Of :attr:`connections`, those that may be to another device (the
        blocking client's count: not the :attr:`resends`).""")

    @property
    def worker_threads(self) -> int:
        """Worker threads started so far (one at a time, never two)."""
        return self._worker.started

    async def connect(self) -> None:
        """Open the line. Raises :class:`~pymb.ModbusConnectionError`.
        Cancelled once the connect has started, the line may still open on
        the worker: :meth:`close` (or the loop's end) closes it."""
        loop = asyncio.get_running_loop()
        if self._guard is None or self._guard.done() or self._guard.get_loop() is not loop:
            # Watched from before the connect starts. (A guard left pending on
            # another loop, closed without its end cancelling the tasks,
            # cannot watch this one.)
            self._closed = loop.create_future()
            self._guard = _watch(self._worker, self._closed, f"pymb-aio guard {self.port}")
        try:
            await self._worker.submit(self.blocking.connect)
        except asyncio.CancelledError:
            raise  # it may open yet: the guard stays
        except BaseException:
            if not self.blocking.connected:  # nothing to watch
                await self._unwatch()
            raise

    async def close(self) -> None:
        """Close the line and end the worker thread; safe to call more than
        once. The request on the line ends at once (within 50 ms) and those
        queued before this close never go out: their awaits raise
        :class:`~pymb.ModbusConnectionError`. The close is done even when
        this await is cancelled (only the wait for it ends)."""
        self._worker.cut()
        done = self._worker.submit(self.blocking.close)
        guard = self._guard
        try:
            await asyncio.shield(done)  # cancelled, the close stays queued
        except asyncio.CancelledError:
            if self._guard is guard and self._closed is not None:
                _release(self._closed)  # the guard ends: the close is queued
                self._guard = self._closed = None
            raise
        self._worker.join_ended()
        if self._guard is guard:
            await self._unwatch()

    async def _unwatch(self) -> None:
        """End the guard task (the client is closed, or never opened): gone
        when this returns, if it is on this loop."""
        guard, closed = self._guard, self._closed
        self._guard = self._closed = None
        if closed is not None:
            _release(closed)
        if guard is not None and guard.get_loop() is asyncio.get_running_loop():
            await asyncio.wait((guard,))

    ensure_connected = Mirror(Client.ensure_connected, setting=True)

    async def __aenter__(self) -> Self:
        await self.connect()
        return self

    async def __aexit__(self, et: type[BaseException] | None, ev: BaseException | None,
                        tb: TracebackType | None) -> None:
        await self.close()

    def __del__(self) -> None:
        # Like the blocking client: dropped while open, the line is closed
        # (on its worker, which then ends), with a warning.
        blocking = getattr(self, "blocking", None)
        if blocking is not None and blocking.connected:
            try:
                warnings.warn(f"unclosed {self!r}: await close() or use `async with`",
                              ResourceWarning, stacklevel=2, source=self)
            finally:
                self._worker.post(blocking.close)
        closed = getattr(self, "_closed", None)
        if closed is not None:  # let the guard task end
            _release(closed)

    def __repr__(self) -> str:
        state = "open" if self.connected else "closed"
        return f"<{type(self).__name__} {self.port} slave={self.slave} {state}>"

    def fileno(self) -> int:
        """The line's file descriptor (-1 when closed)."""
        return self.blocking.fileno()

    # -- running blocking code on the line --------------------------------------------

    def _submit(self, fn: Callable[P, R], /, *args: P.args,
                **kwargs: P.kwargs) -> asyncio.Future[R]:
        return self._worker.request(fn, *args, **kwargs)

    def _submit_setting(self, fn: Callable[P, R], /, *args: P.args,
                        **kwargs: P.kwargs) -> asyncio.Future[R]:
        return self._worker.submit(fn, *args, **kwargs)

    async def run(self, fn: Callable[P, R], /, *args: P.args, **kwargs: P.kwargs) -> R:
        """Run ``fn(*args, **kwargs)`` on this line's worker, in turn with
        the requests, and return its result: several blocking calls on
        :attr:`blocking` that must follow each other with no other request
        between them (a read-modify-write), or a blocking device facade.
        Cancelled before its turn, ``fn`` never runs; after, it runs to its
        end and its result is dropped."""
        if not callable(fn):
            raise InvalidArgument(f"run needs a function to call, got {type(fn).__name__}")
        return await self._worker.request(fn, *args, **kwargs)

    # -- settings ----------------------------------------------------------------------

    @property
    def slave(self) -> int | None:
        """Default slave address for requests that do not name one; a new
        value applies to the requests not yet started."""
        return self.blocking.slave

    @slave.setter
    def slave(self, value: int | None) -> None:
        self.blocking.slave = value

    timeout = Forward[float](
        """Seconds to wait for a complete reply (set with :meth:`set_timeout`,
        in turn with the requests).""")

    set_timeout = Mirror(Client.set_timeout, setting=True)

    # -- requests: the blocking client's, on the worker --------------------------------

    read_holding_registers = Mirror(Client.read_holding_registers)
    read_input_registers = Mirror(Client.read_input_registers)
    read_holding_registers_into = Mirror(Client.read_holding_registers_into)
    read_input_registers_into = Mirror(Client.read_input_registers_into)
    read_registers_prepared = Mirror(Client.read_registers_prepared)
    swap_response_timeout_prepared = Mirror(Client.swap_response_timeout_prepared, setting=True)
    run_read_plan = Mirror(Client.run_read_plan)
    write_register = Mirror(Client.write_register)
    write_registers = Mirror(Client.write_registers)
    mask_write_register = Mirror(Client.mask_write_register)
    write_read_registers = Mirror(Client.write_read_registers)
    read_coils = Mirror(Client.read_coils)
    read_discrete_inputs = Mirror(Client.read_discrete_inputs)
    write_coil = Mirror(Client.write_coil)
    write_coils = Mirror(Client.write_coils)
    report_slave_id = Mirror(Client.report_slave_id)
    read_exception_status = Mirror(Client.read_exception_status)
    raw_request = Mirror(Client.raw_request)
    drain = Mirror(Client.drain)


class _AsyncSerialBase(AsyncClient):
    blocking: RtuClient | AsciiClient

    baudrate = Forward[int]("The line's speed, bit/s.")

    parity = Forward[str]("""``"N"``, ``"E"`` or ``"O"``.""")

    data_bits = Forward[int]("Data bits per character.")

    stop_bits = Forward[int]("Stop bits per character.")

    def frame_time(self, nbytes: int) -> float:
        """Seconds a frame of ``nbytes`` bytes takes on this line (no I/O)."""
        return self.blocking.frame_time(nbytes)


class AsyncRtuClient(_AsyncSerialBase):
    """A Modbus RTU master on a serial port, for asyncio: the arguments of
    :class:`pymb.RtuClient`, the requests as coroutines."""

    blocking: RtuClient

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
        super().__init__(RtuClient(
            port, baudrate, parity, data_bits, stop_bits, slave=slave, timeout=timeout,
            byte_timeout=byte_timeout, serial_mode=serial_mode, rts=rts, rts_delay=rts_delay,
            reject_early=reject_early))

    set_rs485 = Mirror(RtuClient.set_rs485, setting=True)


class _AsyncTcpBase(AsyncClient):
    blocking: TcpClient | RtuOverTcpClient

    host = Forward[str]("The server's name or address.")

    tcp_port = Forward[int]("The server's TCP port.")


class AsyncTcpClient(_AsyncTcpBase):
    """A Modbus TCP client for asyncio: the arguments of
    :class:`pymb.TcpClient`, the requests as coroutines."""

    blocking: TcpClient

    def __init__(self, host: str = "127.0.0.1", port: int | None = None, *,
                 slave: int | None = None, timeout: float = DEFAULT_TIMEOUT,
                 byte_timeout: float = 0.0, tls: TlsConfig | None = None) -> None:
        super().__init__(TcpClient(host, port, slave=slave, timeout=timeout,
                                   byte_timeout=byte_timeout, tls=tls))

    tls = Forward[TlsConfig | None]("Modbus/TCP Security's settings (None: plain Modbus TCP).")

    @property
    def next_tid(self) -> int | None:
        """The transaction id of the client's next request on its open
        connection: None while it is closed, or while a request of the client
        is in flight (read at once, as :attr:`connected` is: the event loop
        never waits for the request to end)."""
        blocking = self.blocking
        lock = blocking._lock  # noqa: SLF001 - the twin's; held while a request is in flight
        if not lock.acquire(blocking=False):
            return None
        try:
            return blocking.next_tid
        finally:
            lock.release()

    attach = Mirror(TcpClient.attach)


class AsyncRtuOverTcpClient(_AsyncTcpBase):
    """RTU frames over TCP for asyncio: the arguments of
    :class:`pymb.RtuOverTcpClient`, the requests as coroutines."""

    blocking: RtuOverTcpClient

    def __init__(self, host: str = "127.0.0.1", port: int = 502, *,
                 slave: int | None = None, timeout: float = DEFAULT_TIMEOUT,
                 byte_timeout: float = 0.0, frame_silence: float = 0.02) -> None:
        super().__init__(RtuOverTcpClient(host, port, slave=slave, timeout=timeout,
                                          byte_timeout=byte_timeout,
                                          frame_silence=frame_silence))


class AsyncAsciiClient(_AsyncSerialBase):
    """Modbus ASCII on a serial line for asyncio: the arguments of
    :class:`pymb.AsciiClient`, the requests as coroutines."""

    blocking: AsciiClient

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
        super().__init__(AsciiClient(port, baudrate, parity, data_bits, stop_bits, slave=slave,
                                     timeout=timeout, byte_timeout=byte_timeout))


class AsyncUdpClient(AsyncClient):
    """Modbus over UDP for asyncio: the arguments of :class:`pymb.UdpClient`,
    the requests as coroutines."""

    blocking: UdpClient

    def __init__(self, host: str = "127.0.0.1", port: int = 502, *,
                 slave: int | None = None, timeout: float = DEFAULT_TIMEOUT,
                 retries: int = 2) -> None:
        super().__init__(UdpClient(host, port, slave=slave, timeout=timeout, retries=retries))

    host = Forward[str]("The server's name or address.")

    udp_port = Forward[int]("The server's UDP port.")

    retries = Forward[int]("How many times an unanswered request is sent again.")
