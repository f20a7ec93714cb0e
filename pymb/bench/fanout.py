"""The bench's bare one-thread loop over many Modbus TCP devices:
:class:`TcpFanout`, the floor `pymb log`'s own loop
(:mod:`pymb.logger.tcploop`) is measured against in ``pymb bench
--sections gateway``: what the same core costs with nothing of the
logger's (no groups, no re-plans, no events, no writer thread).

One epoll waits on every connection at once over non-blocking sockets,
through ``pymb log``'s C loop (:class:`pymb._native.loop.Loop`).
Each device's poll is a fixed list of requests made ready once for the C
core's sans-I/O master (:class:`pymb._native.master.Master`): it frames them
with transaction ids, takes the bytes that come, matches each reply to its
request, checks it with the request path's rules and copies its data bytes
into the device's sample image at their place: the registers, big-endian, as
the store keeps them (bits as the reply packs them). No object per register
or per point is made on the way.

``pipeline`` requests may be in flight on a connection at once (Modbus TCP
allows it, [MB-TCP] 4.2; replies are matched by transaction id); 1 is the
safe default for devices that take one transaction at a time. Flat out, a
poll whose requests all fit the pipeline is the C loop's while it is clean:
its socket wakes once, when all of its replies are in (``SO_RCVLOWAT``),
and one call takes them, sends the next poll and copies the image; one wait
hands this loop many polls. Everything else (a connect, a poll read a
request at a time, a reply that is late, short or refused, a timeout) is
handed back and done here, reply by reply.

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
import select
import socket
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from pymb._native.loop import DONE, GAP, LOOK_MIN, NO_CONN, READY, TAKEN, Loop, look
from pymb._native.master import EXCEPTION, Master, MasterRead, PollTable, ReadBuffer
from pymb.devices.polls import Agenda, Slot
from pymb.errors import InvalidArgument
from pymb.maps.types import BIT_TABLES, TABLE_FUNCTIONS

__all__ = ["FanoutDevice", "FanoutStats", "Sample", "TcpFanout"]

#: (poll start, time.time_ns(); device index; registers): a bytearray, which
#: :mod:`sqlite3` binds as a BLOB at once (a bytes object it first offers to
#: its adapters)
Sample = tuple[int, int, bytearray]


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
    carried: int = 0  #: of all polls, those the C loop read and sent the next of

    @classmethod
    def of(cls, n: int) -> FanoutStats:
        """Zeroed counts of ``n`` devices."""
        return cls([0] * n, [0] * n, [0] * n, [0] * n, [0] * n)


_TICK = 0.05  #: seconds between the checks of timeouts, reconnects and the stop flag
_POLLS = 256  #: polls one wait of the C loop hands over at most
_BLOCK = 1 << 20  #: ... and bytes of their images


class _FanoutConn:
    __slots__ = ("armed", "busy", "deadline", "index", "lowat", "m", "n", "replies", "retry_at",
                 "size", "slot", "sock", "started", "state", "table", "target", "todo", "took")

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
        self.size = d.image_bytes
        self.table = PollTable(reads, d.unit, bytearray(self.size), packed_bits=True)
        self.replies = self.table.ends[self.n]  #: bytes of a whole poll's replies
        self.m = Master()
        self.sock: socket.socket | None = None
        self.state = "closed"  # closed, connecting, open
        self.busy = False
        self.armed = False  #: its polls are the C loop's (flat out, a whole poll in flight)
        self.lowat = 1  #: its socket's SO_RCVLOWAT
        self.todo = 0  #: requests of the poll under way not yet sent
        self.started = 0.0  #: when the poll under way started (monotonic)
        self.took = 0.0  #: seconds a whole poll's replies took, of late
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
        self._stop = threading.Event()
        self._batch: list[Sample] = []
        self._agenda: Agenda[_FanoutConn] = Agenda()  #: the idle devices by their next slot
        self._ep = select.epoll()
        self._rx = ReadBuffer()
        size = max(c.size for c in self._conns)
        polls = max(1, min(_POLLS, _BLOCK // size))
        self._loop = Loop(self._ep.fileno(), len(self._conns), self._rx, LOOK_MIN, polls=polls,
                          block=polls * size, hold=flush, gap=GAP)
        self._block = self._loop.block
        #: wall time less monotonic time, ns, as of the last sweep (a sample's time: its start's)
        self._clock = time.time_ns() - time.monotonic_ns()

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
        c.lowat = 1
        c.deadline = now + self.timeout
        self._ep.register(s.fileno(), select.EPOLLOUT)
        self._loop.bind(c.index, s.fileno())

    def _drop(self, c: _FanoutConn, now: float) -> None:
        if c.armed:
            self._disarm(c)
        if c.sock is not None:
            fd = c.sock.fileno()
            self._loop.unbind(fd)
            with contextlib.suppress(OSError):
                self._ep.unregister(fd)
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
        self._ep.modify(c.sock.fileno(), select.EPOLLIN)
        if self.interval == 0:
            self._start(c, now)

    def _wake_at(self, c: _FanoutConn, size: int) -> None:
        """``c``'s socket is readable once ``size`` bytes came (1: any)."""
        if size != c.lowat and c.sock is not None:
            with contextlib.suppress(OSError):  # (a socket gone bad: its next read says so)
                c.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVLOWAT, size)
                c.lowat = size

    # -- polls ---------------------------------------------------------------------------

    def _start(self, c: _FanoutConn, now: float) -> None:
        c.busy = True
        c.started = now
        c.deadline = now + self.timeout
        n = min(self.pipeline, c.n)
        c.todo = c.n - n
        carried = not self.interval and n == c.n  # the C loop's: flat out, a whole poll
        self._wake_at(c, c.replies if carried else 1)
        if self._send(c, 0, n, now) and carried:
            self._loop.arm(c.index, c.m, c.table, self.timeout, c.took, now,
                           now + look(c.took, self.timeout))
            c.armed = True

    def _disarm(self, c: _FanoutConn) -> None:
        """``c`` is this loop's again (the C loop handed it back, or it is
        taken): its poll in flight read as its replies come."""
        c.armed = False
        t = self._loop.disarm(c.index)
        c.took, c.started, c.deadline = t.took, t.sent_at, t.deadline
        self._wake_at(c, 1)

    def _ended(self, c: _FanoutConn, now: float) -> None:
        """A poll ended (read, refused or lost): the device's next slot, the
        whole slots the poll overran missed."""
        c.busy = False
        if self.interval:
            slot = c.slot
            self.stats.missed[c.index] += slot.advance(now)
            self._agenda.put(slot, c, slot.wake(now))

    def _send(self, c: _FanoutConn, first: int, n: int, now: float) -> bool:
        m = c.m
        size = m.frames(c.table, first, n)
        assert c.sock is not None
        try:
            if c.sock.send(m.view[:size]) == size:
                return True
        except OSError:
            pass
        self.stats.errors[c.index] += 1  # (half a request puts the stream out of step)
        self._drop(c, now)
        return False

    def _sample(self, c: _FanoutConn) -> None:
        """The poll under way read every request: its sample, of its image."""
        self.stats.polls[c.index] += 1
        self._batch.append((self._clock + int(c.started * 1e9), c.index, c.table.image[:]))

    def _carried(self, done: list[int], at: list[float], offs: list[int]) -> None:
        """The C loop read polls of the connections ``done`` in full at
        ``at`` and sent the next ones: their samples, of its block at ``offs``."""
        conns, batch, polls, block, clock = (self._conns, self._batch, self.stats.polls,
                                             self._block, self._clock)
        for i, t, off in zip(done, at, offs, strict=True):
            c = conns[i]
            batch.append((clock + int(c.started * 1e9), i, block[off:off + c.size]))
            c.started = t
            polls[i] += 1
        self.stats.carried += len(done)

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
        if events or used < got:
            self._refused(c, events, used, got, now)
        elif c.todo:
            n = min(before - m.in_flight, c.todo)
            if n:
                c.todo -= n
                self._send(c, c.n - c.todo - n, n, now)
        elif not m.in_flight:
            self._read(c, now)

    def _read(self, c: _FanoutConn, now: float) -> None:
        """The poll under way read every request: its sample; the next poll."""
        self._sample(c)
        self._ended(c, now)
        if self.interval == 0:
            self._start(c, now)

    def _refused(self, c: _FanoutConn, events: int, used: int, got: int, now: float) -> None:
        """``c``'s master took ``got`` bytes, ``used`` of them, with ``events``
        events: an exception ends the poll (the connection is kept when
        nothing else came), anything else is out of step (dropped)."""
        if events and c.m.event(0).kind == EXCEPTION:
            self.stats.exceptions[c.index] += 1
            if not c.m.in_flight and used == got:
                self._ended(c, now)
                return
        else:
            self.stats.errors[c.index] += 1
        self._drop(c, now)

    # -- the loop ------------------------------------------------------------------------

    def _wait(self, timeout: float) -> None:
        """One wait of the C loop: the polls it carried, then what it handed back."""
        loop = self._loop
        got = loop.wait(timeout)
        if loop.done:
            self._carried(loop.done, loop.done_at, loop.done_off)
        recs, conns, now = loop.recs, self._conns, loop.now  # (the records' time, near enough)
        for k in range(got):
            r = recs[k]
            i = r.conn
            if i == NO_CONN:
                continue
            c = conns[i]
            if c.sock is None:  # (closed by a record before: no new socket until a sweep)
                continue
            kind = r.kind
            if kind == DONE:  # read in full (its sample, of its start), the next poll not
                self._sample(c)  # all sent: lost (below)
            if c.armed:
                self._disarm(c)
            if kind == READY:
                if c.state == "open":
                    self._readable(c, now)
                else:
                    self._connected(c, now)
            elif kind == DONE:
                self.stats.errors[i] += 1
                self._drop(c, now)
            elif kind == TAKEN:  # taken but not as a clean poll (looked at: dropped now)
                with contextlib.suppress(OSError):
                    c.sock.recv_into(self._rx.view, r.got, socket.MSG_TRUNC)
                if r.nev or r.used < r.got:
                    self._refused(c, r.nev, r.used, r.got, now)
                elif not c.m.in_flight:
                    self._read(c, now)
            # (LOOK: a slow poll whose replies so far are no clean part of it: read as they come)

    def _due(self, now: float) -> None:
        for c in self._agenda.due(now):
            if c.state == "open":
                self._start(c, now)
            else:  # the slot is missed, and any the loop was away for
                self.stats.missed[c.index] += 1 + c.slot.advance(now)
                self._agenda.put(c.slot, c, c.slot.wake(now))

    def _sweep(self, now: float) -> None:
        loop = self._loop
        for c in self._conns:
            if c.armed:
                if now <= loop.deadline(c.index):
                    continue
                self._disarm(c)  # (its poll is late: it times out below)
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
            self._wait(_TICK)
        now = time.monotonic()
        if self.interval:
            for i, c in enumerate(self._conns):  # the first slots spread over one interval
                c.slot.next_at = now + self.interval * i / len(self._conns)
                self._agenda.put(c.slot, c, c.slot.next_at)
        next_sweep = next_flush = now
        sink, batch, agenda = self.sink, self._batch, self._agenda
        try:
            while not self._stop.is_set():
                now = time.monotonic()
                if end is not None and now >= end:
                    break
                if now >= next_sweep:
                    self._sweep(now)
                    next_sweep = now + _TICK
                    self._clock = time.time_ns() - time.monotonic_ns()
                if agenda.next() <= now:
                    self._due(now)
                if batch and now >= next_flush:
                    sink(batch[:])
                    batch.clear()
                    next_flush = now + self.flush
                self._wait(min(next_sweep, agenda.next()) - now)
        finally:
            for c in self._conns:
                self._drop(c, time.monotonic())
            self._ep.close()
            if batch:
                sink(batch[:])
                batch.clear()
        return self.stats
