"""The bench's bare one-thread loop over many Modbus TCP devices:
:class:`TcpFanout`, the floor `pymb log`'s own loop
(:mod:`pymb.logger.tcploop`) is measured against in ``pymb bench
--sections gateway``: what one selector over non-blocking sockets costs
with nothing of the logger's (no groups, no re-plans, no events, no writer
thread).

One loop waits on every connection at once (the system's selector: epoll
on Linux) over non-blocking sockets. Each device's poll is a fixed list of
requests made ready once for the C core's sans-I/O master
(:class:`pymb._native.master.Master`, the one ``pymb log``'s loop runs on):
it frames them with transaction ids, takes the bytes that come, matches each
reply to its request, checks it with the request path's rules and copies its
data bytes into the device's sample image at their place: the registers,
big-endian, as the store keeps them (bits as the reply packs them). No object
per register or per point is made on the way.

``pipeline`` requests may be in flight on a connection at once (Modbus TCP
allows it, [MB-TCP] 4.2; replies are matched by transaction id); 1 is the
safe default for devices that take one transaction at a time.

Each device polls at ``interval`` seconds on the drift-free slots of the one
schedule ``pymb log`` keeps too (:class:`pymb.devices.polls.Slot`, slot k at
``start + k * interval``, and :class:`~pymb.devices.polls.Agenda`): the
slots a poll overran, and a slot that comes while the device is not
connected, are counted as missed. ``interval`` 0 polls flat out: the next
poll as soon as the last one ends. A poll that takes longer
than ``timeout`` closes the connection (counted); it is opened again after
``retry`` seconds. Finished samples go to ``sink`` in batches (``(t_ns,
device, image)`` tuples) at most every ``flush`` seconds.
"""

from __future__ import annotations

import contextlib
import errno
import selectors
import socket
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from pymb._native.master import EXCEPTION, Master, MasterRead, PollTable, ReadBuffer
from pymb.devices.polls import Agenda, Slot
from pymb.errors import InvalidArgument
from pymb.maps.types import BIT_TABLES, TABLE_FUNCTIONS

__all__ = ["FanoutDevice", "FanoutStats", "Sample", "TcpFanout"]

Sample = tuple[int, int, bytes]  #: (poll start, time.time_ns(); device index; registers)


@dataclass(frozen=True)
class FanoutDevice:
    """One TCP device: where it is and what one poll reads (``(table,
    address, count)`` requests). The sample image holds each table's span,
    from its first address read to its last, in the order the tables first
    come: registers 2 bytes each, big-endian (bits as bytes of 8), so a
    table's part decodes as one block from its first address (see
    :meth:`layout`)."""

    host: str
    port: int
    unit: int
    requests: tuple[tuple[str, int, int], ...]

    def __post_init__(self) -> None:
        if not self.requests:
            raise InvalidArgument(f"{self.host}:{self.port}: a poll needs a request")
        for table, address, count in self.requests:
            if table not in TABLE_FUNCTIONS:
                raise InvalidArgument(f"unknown table {table!r}")
            limit = 2000 if table in BIT_TABLES else 125
            if not (0 <= address <= 0xFFFF and 1 <= count <= limit
                    and address + count <= 0x10000):
                raise InvalidArgument(f"{table} {address}+{count}: not one read")

    def layout(self) -> list[tuple[str, int, int, int]]:
        """``(table, first address, registers, byte offset)`` of each
        table's part of the image."""
        spans: dict[str, list[int]] = {}
        for table, address, count in self.requests:
            lo, hi = spans.setdefault(table, [address, address + count])
            spans[table] = [min(lo, address), max(hi, address + count)]
        out, off = [], 0
        for table, (lo, hi) in spans.items():
            out.append((table, lo, hi - lo, off))
            off += _data_bytes(table, hi - lo)
        return out

    @property
    def image_bytes(self) -> int:
        """Bytes of one sample."""
        return sum(_data_bytes(t, n) for t, _, n, _ in self.layout())


def _data_bytes(table: str, count: int) -> int:
    return (count + 7) // 8 if table in BIT_TABLES else 2 * count


@dataclass
class FanoutStats:
    """Counts, per device and in total."""

    polls: list[int]
    missed: list[int]
    timeouts: list[int]
    exceptions: list[int]
    errors: list[int]  #: connections refused or lost, replies out of step
    started_ns: int = field(default_factory=time.monotonic_ns)

    @classmethod
    def of(cls, n: int) -> FanoutStats:
        """Zeroed counts of ``n`` devices."""
        return cls([0] * n, [0] * n, [0] * n, [0] * n, [0] * n)


class _FanoutConn:
    __slots__ = ("busy", "deadline", "index", "m", "n", "retry_at", "slot", "sock",
                 "started", "state", "table", "target", "todo")

    def __init__(self, index: int, d: FanoutDevice, interval: float) -> None:
        self.index = index
        self.target = d
        self.slot = Slot.every(interval)  #: when it polls (a lost connection: ``retry``)
        base = {t: (first, off) for t, first, _, off in d.layout()}
        reads = []
        for table, address, count in d.requests:
            fc = TABLE_FUNCTIONS[table]
            first, off = base[table]
            if fc <= 2 and (address - first) % 8:
                raise InvalidArgument(f"{table} {address}: bit reads of one table must "
                                      "start 8 bits apart")
            reads.append(MasterRead(fc, address, count, off + _data_bytes(table, address - first)))
        self.n = len(reads)
        self.table = PollTable(reads, d.unit, bytearray(d.image_bytes), packed_bits=True)
        self.m = Master()
        self.sock: socket.socket | None = None
        self.state = "closed"  # closed, connecting, open
        self.busy = False
        self.todo = 0  #: requests of the poll under way not yet sent
        self.started = 0
        self.deadline = 0.0
        self.retry_at = 0.0


class TcpFanout:
    """Polls ``devices`` from one thread until :meth:`stop` or ``run(seconds)``
    ends; see the module's description."""

    def __init__(self, devices: Sequence[FanoutDevice], sink: Callable[[list[Sample]], None], *,
                 interval: float = 1.0, timeout: float = 1.0, retry: float = 1.0,
                 pipeline: int = 1, flush: float = 0.25) -> None:
        if not devices:
            raise InvalidArgument("no devices to poll")
        if not (interval >= 0 and timeout > 0 and retry >= 0 and flush > 0):
            raise InvalidArgument("interval, retry must be >= 0 s; timeout, flush > 0 s")
        if isinstance(pipeline, bool) or not 1 <= pipeline <= 16:
            raise InvalidArgument(f"pipeline must be 1..16, got {pipeline!r}")
        self.devices = tuple(devices)
        self.sink = sink
        self.interval = interval
        self.timeout = timeout
        self.retry = retry
        self.pipeline = pipeline
        self.flush = flush
        self.stats = FanoutStats.of(len(self.devices))
        self._conns = [_FanoutConn(i, d, interval) for i, d in enumerate(self.devices)]
        self._sel = selectors.DefaultSelector()
        self._stop = threading.Event()
        self._batch: list[Sample] = []
        self._agenda: Agenda[_FanoutConn] = Agenda()  #: the idle devices by their next slot
        self._rx = ReadBuffer()

    def stop(self) -> None:
        """Ask :meth:`run` to return (from any thread) within about 50 ms."""
        self._stop.set()

    # -- connections ---------------------------------------------------------------------

    def _connect(self, c: _FanoutConn, now: float) -> None:
        d = c.target
        family = socket.AF_INET6 if ":" in d.host else socket.AF_INET
        s = socket.socket(family, socket.SOCK_STREAM)
        s.setblocking(False)
        s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        rc = s.connect_ex((d.host, d.port))
        if rc not in (0, errno.EINPROGRESS):
            s.close()
            self.stats.errors[c.index] += 1
            c.retry_at = now + self.retry
            return
        c.sock = s
        c.state = "connecting"
        c.deadline = now + self.timeout
        self._sel.register(s, selectors.EVENT_WRITE, c)

    def _drop(self, c: _FanoutConn, now: float) -> None:
        if c.sock is not None:
            with contextlib.suppress(KeyError, ValueError):
                self._sel.unregister(c.sock)
            c.sock.close()
        c.sock = None
        c.state = "closed"
        if c.busy:
            self._ended(c, now)
        c.m.reset()
        c.retry_at = now + self.retry

    def _connected(self, c: _FanoutConn, now: float) -> None:
        assert c.sock is not None
        if c.sock.getsockopt(socket.SOL_SOCKET, socket.SO_ERROR):
            self.stats.errors[c.index] += 1
            self._drop(c, now)
            return
        c.state = "open"
        self._sel.modify(c.sock, selectors.EVENT_READ, c)
        if self.interval == 0:
            self._start(c, now)

    # -- polls ---------------------------------------------------------------------------

    def _start(self, c: _FanoutConn, now: float) -> None:
        c.busy = True
        c.started = time.time_ns()
        c.deadline = now + self.timeout
        n = min(self.pipeline, c.n)
        c.todo = c.n - n
        self._send(c, c.n - c.todo - n, n, now)

    def _ended(self, c: _FanoutConn, now: float) -> None:
        """A poll ended (read, refused or lost): the device's next slot, the
        whole slots the poll overran missed."""
        c.busy = False
        if self.interval:
            slot = c.slot
            self.stats.missed[c.index] += slot.advance(now)
            self._agenda.put(slot, c, slot.wake(now))

    def _send(self, c: _FanoutConn, first: int, n: int, now: float) -> None:
        m = c.m
        size = m.frames(c.table, first, n)
        assert c.sock is not None
        try:
            c.sock.send(m.view[:size])
        except OSError:
            self.stats.errors[c.index] += 1
            self._drop(c, now)

    def _readable(self, c: _FanoutConn, now: float) -> None:
        sock = c.sock
        assert sock is not None
        rx = self._rx
        try:
            got = sock.recv_into(rx.view)
        except BlockingIOError:
            return
        except OSError:
            got = 0
        if not got or not c.busy:  # closed by the device, or a reply nobody asked for
            self.stats.errors[c.index] += 1
            self._drop(c, now)
            return
        m = c.m
        before = m.in_flight
        events, used = m.take(rx, 0, got, c.table)
        if events or used < got:  # an exception (the poll fails), or no reply of this poll
            if events and m.event(0).kind == EXCEPTION:
                self.stats.exceptions[c.index] += 1
                if m.in_flight:  # more replies are on their way: start afresh
                    self._drop(c, now)
                    return
                self._ended(c, now)
                return
            self.stats.errors[c.index] += 1
            self._drop(c, now)
            return
        if c.todo:
            n = min(before - m.in_flight, c.todo)
            if n:
                c.todo -= n
                self._send(c, c.n - c.todo - n, n, now)
        elif not m.in_flight:
            self._ended(c, now)
            self.stats.polls[c.index] += 1
            self._batch.append((c.started, c.index, bytes(c.table.image)))
            if self.interval == 0:
                self._start(c, now)

    # -- the loop ------------------------------------------------------------------------

    def _due(self, now: float) -> None:
        for c in self._agenda.due(now):
            if c.state == "open":
                self._start(c, now)
            else:  # the slot is missed, and any the loop was away for
                self.stats.missed[c.index] += 1 + c.slot.advance(now)
                self._agenda.put(c.slot, c, c.slot.wake(now))

    def _sweep(self, now: float) -> None:
        for c in self._conns:
            if c.state == "closed":
                if now >= c.retry_at:
                    self._connect(c, now)
            elif not c.busy and c.state == "open" and self.interval == 0:
                self._start(c, now)  # flat out, after a poll that failed
            elif (c.busy or c.state == "connecting") and now > c.deadline:
                self.stats.timeouts[c.index] += 1
                self._drop(c, now)

    def run(self, seconds: float | None = None) -> FanoutStats:
        """Poll until :meth:`stop` or for ``seconds``; returns the counts."""
        now = time.monotonic()
        end = None if seconds is None else now + seconds
        for c in self._conns:
            self._connect(c, now)
        # the first slots come once the connections are made (or failed), timeout at most
        while any(c.state == "connecting" for c in self._conns) and not self._stop.is_set() \
                and time.monotonic() < now + self.timeout:
            for key, _ in self._sel.select(0.05):
                if key.data.state == "connecting":
                    self._connected(key.data, time.monotonic())
        now = time.monotonic()
        if self.interval:
            for i, c in enumerate(self._conns):  # the first slots spread over one interval
                c.slot.next_at = now + self.interval * i / len(self._conns)
                self._agenda.put(c.slot, c, c.slot.next_at)
        next_sweep = next_flush = now
        select, sink, batch, agenda = self._sel.select, self.sink, self._batch, self._agenda
        try:
            while not self._stop.is_set():
                now = time.monotonic()
                if end is not None and now >= end:
                    break
                if now >= next_sweep:
                    self._sweep(now)
                    next_sweep = now + 0.05
                if agenda.next() <= now:
                    self._due(now)
                if batch and now >= next_flush:
                    sink(batch[:])
                    batch.clear()
                    next_flush = now + self.flush
                wait = min(next_sweep, agenda.next()) - now
                for key, mask in select(max(wait, 0.0)):
                    c = key.data
                    if c.state == "open":
                        self._readable(c, now)
                    elif mask & selectors.EVENT_WRITE:
                        self._connected(c, now)
        finally:
            for c in self._conns:
                self._drop(c, time.monotonic())
            self._sel.close()
            if batch:
                sink(batch[:])
                batch.clear()
        return self.stats
