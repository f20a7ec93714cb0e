"""A Modbus TCP upstream with several transactions in flight at once: Modbus
TCP's transaction id lets a device (or a gateway) take a request before the
one before it is answered, so ``pymb serve`` sends the clients' requests
without waiting, each under its own upstream transaction id, at most
``max_inflight`` of them, and hands each reply to the client that asked."""

from __future__ import annotations

import asyncio
import collections
from collections.abc import Callable

from pymb._native.serve import (
    REPLY_BAD,
    REPLY_EXCEPTION,
    REPLY_OTHER,
    BadFrame,
    check_reply,
    mbap_frame,
    take_frames,
)
from pymb.serve.upstream import EX_PATH, EX_TARGET, Done, Wanted, reads_only

__all__ = ["DEFAULT_MAX_INFLIGHT", "PipelinedUpstream"]

#: transactions in flight to a Modbus TCP upstream unless --max-inflight says
DEFAULT_MAX_INFLIGHT = 8


class _Link(asyncio.Protocol):
    """The TCP connection to the upstream: replies split by their MBAP length
    (the C core's rule)."""

    def __init__(self, owner: PipelinedUpstream) -> None:
        self.owner = owner
        self.buf = bytearray()
        self.transport: asyncio.Transport | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self.transport = transport

    def data_received(self, data: bytes) -> None:
        self.buf += data
        try:
            frames = take_frames(self.buf)
        except BadFrame as e:
            self.owner.lost(self, f"the upstream sent bytes that are not Modbus TCP ({e})")
            return
        for frame in frames:
            self.owner.reply(frame)

    def connection_lost(self, exc: Exception | None) -> None:
        self.owner.lost(self, f"{exc}" if exc else "closed by the upstream",
                        closed=exc is None or isinstance(exc, (ConnectionResetError,
                                                               BrokenPipeError)))


class _Job:
    __slots__ = ("answers_before", "done", "pdu", "resent", "timer", "unit", "wanted")

    def __init__(self, unit: int, pdu: bytes, done: Done, wanted: Wanted) -> None:
        self.unit, self.pdu, self.done, self.wanted = unit, pdu, done, wanted
        self.timer: asyncio.TimerHandle | None = None
        self.answers_before = 0  #: its unit's replies when it was sent
        self.resent = False  #: sent again after a reset that came before any reply


class PipelinedUpstream:
    """Requests to a Modbus TCP device at ``host:port``, up to
    ``max_inflight`` at once on one connection, each under its own upstream
    transaction id. Runs on the server's event loop: :meth:`submit` is called
    there and ``done`` is called there with the reply PDU (the device's reply
    or exception, 0x0B when it did not answer within ``timeout``, 0x0A when it
    cannot be reached). A reply is taken only with the transaction id, unit
    and function of a request in flight; anything else is dropped. A reply
    that fails the request path's check of its request (a byte count that
    disagrees with it, a write's echo that differs) is answered 0x0B, as
    when one transaction at a time goes upstream.

    Some devices drop a request that arrives while they are busy with
    another (pymodbus's TCP server answers only the first of requests that
    arrive together): when a unit leaves a request unanswered past
    ``timeout`` while it answered others, ``max_inflight`` falls to 1, said
    in one event line. A unit that answers nothing (a device that is off,
    behind a gateway) changes nothing.

    Some devices take one request a connection: when the device closes the
    connection after a reply, the reads that were in flight on it are sent
    again on a new one, first (a write never is: the device may have done
    it, and it is answered 0x0A), and when it closed after its first
    reply with others in flight, ``max_inflight`` falls to 1, said in one
    event line."""

    def __init__(self, host: str, port: int, *, timeout: float,
                 max_inflight: int = DEFAULT_MAX_INFLIGHT, depth: int = 1024,
                 on_event: Callable[[str], None] | None = None) -> None:
        self.host, self.port = host, port
        self.timeout = timeout
        self.max_inflight = max_inflight
        self.depth = depth
        self._on_event = on_event or (lambda _text: None)
        self._queue: collections.deque[_Job] = collections.deque()
        self._inflight: dict[int, _Job] = {}
        self._next_tid = 0
        self._answers: dict[int, int] = {}  # unit -> replies from it so far
        self._link: _Link | None = None
        self._served = 0  # replies on the connection open now
        self._connecting: asyncio.Task[None] | None = None
        self._down_said = False
        self._stopped = False
        #: transactions sent, and how each ended; the most in flight at once
        self.sent = self.timeouts = self.exceptions = self.unreachable = 0
        self.dropped = 0  #: requests queued or in flight when it stopped: never answered
        self.unwanted = 0  #: requests whose client had gone before their turn: never sent
        self.abandoned = False  #: as Upstream's: never (no thread of its own)
        self.most_inflight = 0

    def start(self) -> None:
        """Nothing to start: the connection is opened at the first request."""

    def stop(self, timeout: float = 5.0) -> None:
        """Drop what is queued and in flight (their clients are gone with the
        server) and close the connection."""
        self._stopped = True
        self.dropped += len(self._queue) + len(self._inflight)
        self._queue.clear()
        for job in self._inflight.values():
            if job.timer is not None:
                job.timer.cancel()
        self._inflight.clear()
        if self._connecting is not None:
            self._connecting.cancel()
        if self._link is not None and self._link.transport is not None:
            self._link.transport.abort()
        self._link = None

    def submit(self, unit: int, pdu: bytes, done: Done, wanted: Wanted = None) -> None:
        """Queue request ``pdu`` for ``unit`` (on the event loop); when its
        turn comes, it is not sent if ``wanted()`` says its client has gone
        (counted in :attr:`unwanted`)."""
        if len(self._queue) >= self.depth:
            done(bytes((pdu[0] | 0x80, EX_TARGET)))
            return
        self._queue.append(_Job(unit, pdu, done, wanted))
        self._pump()

    def _pump(self) -> None:
        if self._stopped:
            return
        if self._link is None:
            if self._connecting is None and self._queue:
                self._connecting = asyncio.get_running_loop().create_task(self._connect())
            return
        transport = self._link.transport
        assert transport is not None
        loop = asyncio.get_running_loop()
        while self._queue and len(self._inflight) < self.max_inflight:
            job = self._queue.popleft()
            if job.wanted is not None and not job.wanted():
                self.unwanted += 1
                continue
            tid = self._take_tid()
            self._inflight[tid] = job
            job.answers_before = self._answers.get(job.unit, 0)
            job.timer = loop.call_later(self.timeout, self._late, tid)
            self.sent += 1
            transport.write(mbap_frame(tid, job.unit, job.pdu))
        self.most_inflight = max(self.most_inflight, len(self._inflight))

    def _take_tid(self) -> int:
        for _ in range(0x10000):
            tid = self._next_tid
            self._next_tid = (tid + 1) & 0xFFFF
            if tid not in self._inflight:
                return tid
        raise AssertionError("more than 65536 transactions in flight")  # max_inflight <= 65535

    async def _connect(self) -> None:
        loop = asyncio.get_running_loop()
        try:
            _t, link = await asyncio.wait_for(loop.create_connection(
                lambda: _Link(self), self.host, self.port), self.timeout)
        except (TimeoutError, OSError) as e:
            why = getattr(e, "strerror", None) or str(e) or "no connection within the timeout"
            if not self._down_said:
                self._down_said = True
                self._on_event(f"upstream unreachable: cannot connect to {self.host}:"
                               f"{self.port}: {why} (answering 0x0A)")
            queued, self._queue = self._queue, collections.deque()
            for job in queued:
                self.unreachable += 1
                job.done(bytes((job.pdu[0] | 0x80, EX_PATH)))
            return
        finally:
            self._connecting = None
        if self._stopped:
            if link.transport is not None:
                link.transport.abort()
            return
        if self._down_said:
            self._on_event("upstream reachable again")
            self._down_said = False
        self._link, self._served = link, 0
        self._pump()

    def reply(self, frame: bytes) -> None:
        """A reply frame from the upstream (on the loop)."""
        tid = frame[0] << 8 | frame[1]
        job = self._inflight.get(tid)
        if job is None:
            return  # late (already answered 0x0B), or to no request
        how = check_reply(job.unit, job.pdu, frame)
        if how == REPLY_OTHER:
            return  # not a reply to it
        del self._inflight[tid]
        self._served += 1
        if job.timer is not None:
            job.timer.cancel()
        if how == REPLY_BAD:
            self.timeouts += 1
            job.done(bytes((job.pdu[0] | 0x80, EX_TARGET)))
        else:
            self.exceptions += how == REPLY_EXCEPTION
            self._answers[job.unit] = self._answers.get(job.unit, 0) + 1
            job.done(frame[7:])
        self._pump()

    def _late(self, tid: int) -> None:
        job = self._inflight.pop(tid, None)
        if job is None:
            return
        self.timeouts += 1
        if self.max_inflight > 1 and self._answers.get(job.unit, 0) > job.answers_before:
            # the unit answered others while this one waited: it drops (or
            # cannot keep up with) requests that come while it is busy
            self.max_inflight = 1
            self._on_event(f"upstream unit {job.unit} answered other requests but not one "
                           f"sent with them within {self.timeout:g} s: one transaction at a "
                           "time from now")
        job.done(bytes((job.pdu[0] | 0x80, EX_TARGET)))
        self._pump()

    def lost(self, link: _Link, why: str, *, closed: bool = False) -> None:
        """The connection ended (``closed``: the device closed or reset it)
        or the upstream sent garbage: what was in flight is answered 0x0A,
        but for the reads the device closed it on after a reply, sent again
        first on the next connection (each connection that carried a reply
        is progress: the queue's head is answered); the next request
        connects again."""
        if link is not self._link:
            return
        self._link = None
        if link.transport is not None:
            link.transport.abort()
        if self._stopped:
            return
        inflight, self._inflight = list(self._inflight.values()), {}
        # A device that answers one request a connection resets it when more
        # were sent: its one reply can be lost with the reset. So with several
        # in flight, a reset before any reply sends the reads again too (each
        # read once that way: a device that resets at once ends it).
        several = len(inflight) > 1
        again = [job for job in inflight if closed and reads_only(job.pdu) and (
            self._served or (several and not job.resent))]
        for job in again:
            job.resent = job.resent or not self._served
        if closed and self.max_inflight > 1 and (
                (self._served == 1 and inflight) or (not self._served and several)):
            self.max_inflight = 1
            how = ("closed the connection after one reply with" if self._served else
                   "reset the connection before any reply was read, with")
            self._on_event(f"upstream {how} {len(inflight)} more request(s) sent: one "
                           "transaction at a time from now")
        elif len(again) < len(inflight) or not self._served:
            self._on_event(f"upstream connection lost: {why}")
        for job in inflight:
            if job.timer is not None:
                job.timer.cancel()
            if job in again:
                continue
            self.unreachable += 1
            job.done(bytes((job.pdu[0] | 0x80, EX_PATH)))
        self._queue.extendleft(reversed(again))
        self._pump()
