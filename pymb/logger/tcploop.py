"""Every map device on every plain Modbus TCP bus of a run, polled from one
thread: :class:`TcpMapPoller`.

One epoll waits on every connection at once over non-blocking sockets: a connection per bus (per
``host:port``), shared by the devices behind it (a TCP gateway's unit ids). A connection carries
one poll at a time, a device's group; its requests go out ``pipeline`` at a time (1 by default,
as a gateway to a serial line needs), framed by the connection's C master
(:class:`pymb._native.master.Master`, the sans-I/O core) into one write; the master takes the
replies as they come (:mod:`pymb.logger.tcpreplies` reads them), matches them by transaction id,
checks them with the request path's rules and copies their data into the group's sample image.
While a whole poll is out (or the rest of one longer than the pipeline, its last request sent),
the socket wakes the loop once, when the bytes of all of its replies are in (``SO_RCVLOWAT``); a
poll whose replies take more than twice as long as they did of late (an exception reply is
shorter than the reply it stands for) is read as its replies come. Flat out, a connection whose
next poll is the same requests at once is the loop's C part's (:mod:`pymb._native.loop`: it
reads the replies and sends the next poll) until anything else is to happen on it. This module
is the runner: the sockets, and the logger's one schedule (:mod:`pymb.logger.schedule`, as a
thread per bus runs it): each group at its own interval on drift-free slots, skipped slots
counted; ``offline_after`` / ``offline_retry`` per device; an exception re-plans within the same
poll as the planner's policy says (:func:`pymb.maps.planner.on_refusal`: 02/03 with
``split_on_exception``; a point refused alone reads ``unsupported``); samples and events go to
the writer's queue as :class:`~pymb.store.Sample` and :class:`~pymb.store.Event` records, the
registers stored as a thread per bus would store them.
"""

from __future__ import annotations

import errno
import math
import os
import queue
import threading
import time

from pymb._native import exception_errno
from pymb._native.loop import DONE, END, LOOK_MIN, READY, TAKEN, UNSENT, look
from pymb._native.master import PollTable
from pymb._native.serve import mbap_frame
from pymb.client.address import parse_host_port
from pymb.devices.mapreading import GroupDecode
from pymb.errors import ModbusConnectionError, ModbusError
from pymb.logger.config import BusConfig
from pymb.logger.poller import map_info
from pymb.logger.schedule import TEXT, Agenda
from pymb.logger.stats import Stats
from pymb.logger.tcpbase import TcpLoopBase
from pymb.logger.tcpconn import Conn, fans_out
from pymb.logger.tcplend import Lender
from pymb.logger.tcpreplies import TcpReplies
from pymb.logger.tcpsel import WRITABLE
from pymb.logger.tcpunits import Entry, PollRequest, Unit, asked, request_failed
from pymb.maps.device_plan import MapItems, PointPlanner
from pymb.maps.planner import on_refusal
from pymb.store import Event, Sample
from pymb.store.block import PollBlock

__all__ = ["TcpMapPoller", "fans_out"]

#: a connection the device closed (EOF) or reset
_CLOSED = (errno.ECONNRESET, errno.EPIPE)
_TICK = 0.05  #: seconds between the checks of timeouts, reconnects and the stop flag


class TcpMapPoller(TcpLoopBase):
    """Polls the map devices of ``buses`` (each :func:`fans_out`) until
    ``stop`` is set; puts Samples and Events on ``out`` as a
    :class:`~pymb.logger.poller.BusPoller` does."""

    def __init__(self, buses: list[BusConfig], out: queue.Queue[list[Sample | Event | PollBlock]],
                 stop: threading.Event, stats: Stats) -> None:
        super().__init__(out, stop, stats)
        #: the reading side; it tells this poller what came (as its ``Polls``)
        self.replies = TcpReplies(self)
        planners: dict[int, tuple[PointPlanner, MapItems]] = {}
        decoders: dict[tuple[int, str | None], GroupDecode] = {}
        for bus in buses:
            host, port = parse_host_port(str(bus.tcp), what=f"bus {bus.name!r}: tcp")
            units, entries = [], []
            for d in bus.devices:
                u = Unit.of(map_info(bus, d), d, bus.timeout, planners)
                units.append(u)
                for group, interval in d.polls:
                    entries.append(Entry.of(u, group, bus.interval if interval is None
                                            else interval, interval == 0, decoders))
            self.conns.append(Conn(bus, host, port, units, entries, max(1, bus.pipeline)))
            stats.opened.setdefault(bus.name, False)
        self.bus_names = [b.name for b in buses]
        self._agenda: Agenda[Entry] = Agenda()  #: the groups by when they fall due
        self._conn_of = {id(e): c for c in self.conns for e in c.entries}
        self._silent: set[Conn] = set()  #: connections waiting out a device's silence
        #: lends a poll connection to a write command's thread between two polls
        self.lender = Lender(self._sel, self._sweep_now)
        self.start_loop(self.replies.rx, LOOK_MIN)

    def _sweep_now(self) -> None:
        """A sweep of every connection at once (from a borrower's thread: it
        lends idle connections)."""
        self.loans += 1
        self._soonest = 0.0

    # -- polls ---------------------------------------------------------------------------

    def lost(self, c: Conn, now: float, why: str, err: int | None) -> None:
        """The connection failed: the device of the poll under way is told
        (else the bus), and the bus is opened again (:meth:`reopen`). A
        connection the device closed after replying is no failure
        (:meth:`_closed_after_replies`)."""
        if err in _CLOSED and c.answered_here > 0 and not c.m.kept:
            self._closed_after_replies(c, now)
            return
        e = c.entry
        pending = c.pending()
        spec = pending[0] if pending else (c.todo[0] if c.todo else None)
        retry = self.reopen(c, now)
        if e is not None:
            exc = ModbusConnectionError(
                f"{asked(spec, e.unit)} on {c.bus.endpoint}: {why}", errno=err)
            self.failed(c, e, exc, now)
        else:  # between polls: the bus's event
            self.report.bus_fault(c.bus.name, why, "connection", TEXT["lost"].format(
                endpoint=c.bus.endpoint, why=why, retry=retry))

    def _not_open(self, c: Conn, now: float, why: str) -> None:
        e, c.resume, c.renew = c.resume, None, False
        super()._not_open(c, now, why)
        if e is not None:  # the poll that waited for the connection fails with it
            self.failed(c, e, ModbusConnectionError(
                f"{asked(None, e.unit)} on {c.bus.endpoint}: {why}"), now)

    def _queue(self, c: Conn, e: Entry) -> None:
        if not e.queued:
            e.queued = True
            if c.armed:  # (the next poll is no longer the same one at once)
                self.synced(c)
            c.waiting.append(e)

    def _next(self, c: Conn, now: float) -> None:
        """Start the next waiting poll on an idle open connection."""
        if c.loan is not None and self.lender.lend(c):  # lent to a write command
            return
        while c.entry is None and c.waiting and c.state == "open":
            e = c.waiting.popleft()
            e.queued = False
            if not e.slot.due(now):
                self._agenda.put(e.slot, e, e.slot.wake(now))
                continue
            self._begin(c, e, now)

    def _begin(self, c: Conn, e: Entry, now: float) -> None:
        """Start a poll of ``e`` on ``c`` (open and idle)."""
        c.entry = e
        c.todo = e.requests()
        c.table = e.table
        c.sent = 0
        if c.unread:
            c.unread.clear()
        if not c.todo:  # every point refused: the poll reads nothing
            self._done(c, e, now)
            return  # (a flat-out one again after the next select, not in a loop here)
        self._send(c, now)

    def _send(self, c: Conn, now: float) -> None:
        """Send the poll's next requests: as many as the pipeline has room
        for (one at a time for a device that needs silences around its
        requests, and after a silence it asked for)."""
        e = c.entry
        assert e is not None
        sock = c.sock
        assert sock is not None
        u = e.unit
        m = c.m
        pipe = c.pipeline
        if u.timed or c.quiet_until > now:
            if u.timed:
                pipe = 1
            at = max(c.quiet_until, c.last_end + u.gap) if u.timed else c.quiet_until
            if at > now:
                if not m.in_flight:
                    c.deadline = at  # the loop sends when the silence is over
                    self._silent.add(c)
                return
        busy = m.in_flight
        todo = len(c.todo)
        n = min(pipe - busy, todo - c.sent)
        if c.limit and n > c.limit - c.asked:
            n = c.limit - c.asked
            if n <= 0 and not busy:
                self._renew(c, now)  # this connection carried what it can
        if n <= 0:
            return
        t = c.table
        assert t is not None
        self._out(c, t, n, m.frames(t, c.sent, n), busy, now)

    def _out(self, c: Conn, t: PollTable, n: int, size: int, busy: int, now: float) -> None:
        """``n`` requests of the poll under way, ``size`` bytes framed in its
        master's buffer (``busy`` were in flight before them): sent, the
        poll's deadline and wake-up set."""
        e = c.entry
        sock = c.sock
        assert e is not None
        assert sock is not None
        u = e.unit
        todo = len(c.todo)
        c.sent += n
        c.asked += n
        if not busy:
            c.deadline = deadline = now + u.timeout
            if deadline < self._soonest:
                self._soonest = deadline
        arm, look_at = False, math.inf
        if n != todo or n == 1 or u.timed:  # woken by each reply (one, or a poll
            if c.lowat != 1:  # longer than the pipeline)
                c.wake_at(1)
        else:  # the whole poll at once: one wake-up for its replies
            if c.lowat != t.ends[n]:
                c.wake_at(t.ends[n])
            c.whole = True
            c.sent_at = now
            look_at = now + look(c.took, u.timeout)
            arm = self.again(c, e, now) is not None  # its polls the C part's from now on
            if not arm:
                self.look(c, look_at)
        try:  # whole, or the connection is lost
            sent = sock.send(c.m.view[:size])
        except BlockingIOError:
            sent = 0
        except OSError as err:
            sent, arm = -(err.errno or errno.EPIPE), False
        if sent != size:
            self._unsent(c, now, size, sent)
        elif arm:
            self.arm(c, t, u.timeout, look_at)
        elif not busy and e.slot.interval and c.waiting:  # it and those due after it: a chain
            chain = c.chain_of(e, now)
            if len(chain) > 1:  # (one poll alone costs more carried than read here)
                self.chain(c, chain, now, look_at)

    def _unsent(self, c: Conn, now: float, size: int, sent: int) -> None:
        """``sent`` of a poll's ``size`` bytes went out (negative: the send's
        errno): the connection is lost (half a request puts the stream out of step)."""
        self.lost(c, now, os.strerror(-sent) if sent < 0 else
                  f"the connection took {sent} of {size} request bytes (the device does "
                  "not read its requests)", -sent if sent < 0 else None)

    def refused(self, c: Conn, e: Entry, spec: PollRequest, code: int, tid: int,
                now: float) -> None:
        """The device answered ``spec`` (transaction ``tid``) with exception
        ``code``: re-planned within the poll as the planner's policy says,
        else the poll fails, said as a client says it (the frame that came:
        the one exception reply the master takes for it)."""
        u = e.unit
        refusal = on_refusal(u.planner, spec.request, code)
        if refusal is not None:  # the poll goes on (the reader calls progress)
            c.unread.update(refusal.unsupported)
            if refusal.requests:
                subs = [e.spec(s) for s in refusal.requests]
                c.todo = [*c.todo[:c.sent], *subs, *c.todo[c.sent:]]
                c.table = e.table_of(c.todo)
            return
        got = mbap_frame(tid, u.info.address, bytes((spec.function | 0x80, code)))
        exc = request_failed(exception_errno(code), c.bus.endpoint, spec, u, got)
        c.forget()  # replies still on their way are skipped as late ones
        c.entry = None
        self.failed(c, e, exc, now)
        self._next(c, now)

    def progress(self, c: Conn, e: Entry, now: float) -> None:
        """Replies (or refusals) came for the poll under way: the next of
        its requests go out, or it is done."""
        u = e.unit
        if u.timed:
            c.last_end = now
            c.quiet_until = max(c.quiet_until, now + u.turnaround)
        if c.sent < len(c.todo):
            self._send(c, now)
            if c.armed:  # the C part carries the rest of it
                return
        m = c.m
        if not m.in_flight:
            if c.sent < len(c.todo):
                return  # (waiting for a silence)
            if c.whole:
                c.took += (now - c.sent_at - c.took) / 8
            self.sample(c, e, now)
            slot = e.slot
            if (not slot.interval and not slot.once and not c.waiting and c.loan is None
                    and c.state == "open" and now >= slot.health.retry_at):
                self._begin(c, e, now)  # flat out, no other poll waiting: at once again
                return
            self._requeue(c, e, now)
            self._next(c, now)
        else:
            c.deadline = now + u.timeout  # the rest of the poll's replies are on their way
            if c.sent == len(c.todo) and not u.timed:  # one wake for them all
                t = c.table
                assert t is not None
                lowat = c.lowat
                c.wake_at(max(1, sum(t.sizes[k] for k in m.pending()) - m.kept))
                if lowat == 1 < c.lowat:  # (read as they come if slower than a look)
                    self.look(c, now + look(c.took, u.timeout))

    def restarted(self, c: Conn, e: Entry, now: float) -> None:
        """``e``'s poll read every request and its next one is framed
        (:meth:`again`): the poll's sample, and the next poll sent."""
        c.took += (now - c.sent_at - c.took) / 8
        self.sample(c, e, now)
        c.entry = e
        c.sent = 0
        t = c.table
        assert t is not None
        self._out(c, t, t.n, c.m.framed, 0, now)

    def _done(self, c: Conn, e: Entry, now: float) -> None:
        """A poll read every request: its sample; the group's next slot."""
        self.sample(c, e, now)
        self._requeue(c, e, now)

    def _requeue(self, c: Conn, e: Entry, now: float) -> None:
        """After a poll (or a failed one): the group's next slot (whole slots
        a long poll overran skipped and counted); queued at once when due."""
        slot = e.slot
        late = slot.advance(now)
        if late:
            self.report.skipped(c.bus.name, slot, late)
        if slot.due(now):
            self._queue(c, e)
        else:
            self._agenda.put(slot, e, slot.wake(now))

    def failed(self, c: Conn, e: Entry, exc: ModbusError, now: float) -> None:
        """A poll of ``e`` failed with ``exc``: counted and said; the group's next slot."""
        u = e.unit
        self.report.error(c.bus.name, u.health, u.info, exc, now)
        self._requeue(c, e, now)

    # -- the loop ------------------------------------------------------------------------

    def _sweep(self, now: float) -> None:
        self._soonest = soonest = float("inf")
        for c in self.sweeping(now, _TICK):
            if c.armed and self.armed_on(c, now, _TICK):
                continue
            if c.state == "closed":
                if now >= c.retry_at:
                    self._connect(c, now)
            elif c.state == "connecting":
                if now >= c.deadline:
                    self._close(c)
                    self._not_open(c, now, f"cannot connect to {c.bus.endpoint}: no answer "
                                           f"within {c.bus.timeout:g} s")
            elif c.entry is not None and now >= c.deadline:
                if c.busy and c.lowat > 1:
                    c.wake_at(1)
                    self.replies.readable(c, now)  # what came before the time was up
                if c.entry is not None and now >= c.deadline:
                    if c.busy:
                        self._timeout(c, now)
                    elif c.sent < len(c.todo):
                        self._send(c, now)  # a silence is over
            elif c.entry is None and (c.waiting or c.loan is not None):
                self._next(c, now)
            if (c.state == "connecting" or c.busy) and c.deadline < soonest:
                soonest = c.deadline
        self._soonest = min(self._soonest, soonest)

    def _timeout(self, c: Conn, now: float) -> None:
        e = c.entry
        assert e is not None
        spec = c.pending()[0]
        u = e.unit
        got = c.m.partial() or None
        exc = request_failed(errno.ETIMEDOUT, c.bus.endpoint, spec, u, got, c.m.dropped())
        c.forget()  # a late reply is skipped by its transaction id
        c.entry = None
        self.failed(c, e, exc, now)
        if got:  # a part of a reply (one whose length lied?): the stream is out of step
            self.reopen(c, now)
        self._next(c, now)

    def _quiet_over(self, now: float) -> float:
        """Send what waited for a silence that is over; seconds to the next."""
        wait = _TICK
        for c in list(self._silent):
            if c.entry is None or c.busy or c.sock is None:
                self._silent.discard(c)
            elif c.deadline <= now:
                self._silent.discard(c)
                self._send(c, now)
            else:
                wait = min(wait, c.deadline - now)
        return wait

    def _due(self, now: float) -> None:
        conns = []  # (all queued first: each connection's first poll chains the others)
        for e in self._agenda.due(now):
            c = self._conn_of[id(e)]
            self._queue(c, e)
            conns.append(c)
        for c in conns:
            if c.entry is None:
                self._next(c, now)

    def run(self) -> None:
        try:
            self._run()
        finally:
            self.flush()
            for c in self.conns:
                self._close(c)
            self.lender.close()
            self._sel.close()

    def _run(self) -> None:
        start = time.monotonic()
        for c in self.conns:
            for e in c.entries:
                e.slot.next_at = start
                if e.slot.interval:
                    self._agenda.put(e.slot, e, start)
        stop, lender, cloop, conns = self.stop_event, self.lender, self.cloop, self.conns
        assert cloop is not None
        owner, recs, carried, looks = self._sel.owner, cloop.recs, self.carried, self._looks
        next_sweep = start
        while not stop.is_set():
            now = time.monotonic()
            if now >= next_sweep or now >= self._soonest:
                self._sweep(now)
                next_sweep = now + _TICK
            agenda = self._agenda.next()
            if agenda <= now:
                self._due(now)
                agenda = self._agenda.next()
            if self.report.aged(now):
                self.flush()
            soonest = self._soonest
            wait = (next_sweep if next_sweep < soonest else soonest) - now
            if agenda < now + wait:
                wait = agenda - now
            if self._silent:
                wait = min(wait, self._quiet_over(now))
            if looks and looks[0][0] <= now:
                for c in self.looks_due(now):  # read a poll's replies as they come
                    c.wake_at(1)
                    self.replies.readable(c, now)
            if looks and looks[0][0] - now < wait:
                wait = looks[0][0] - now
            got = cloop.wait(wait)
            now = cloop.now  # (when it looked)
            if cloop.done:  # the usual: polls read, the next ones sent
                for c, e, at in self.carried_block(cloop.done, cloop.done_at, cloop.done_off):
                    self._requeue(c, e, at)  # (a chain's)
            for i in range(got):
                r = recs[i]
                kind = r.kind
                if kind != READY:  # handed back: a poll not all sent, a take, a look, an end
                    c = conns[r.conn]
                    if kind == DONE:  # (its sample first, then the loss)
                        carried(c, r.now)
                    self.synced(c)
                    if kind in (DONE, UNSENT):
                        self._unsent(c, r.now, r.size, -r.err if r.err else r.sent)
                    elif kind == END:  # a chain read: the next poll waiting
                        self._next(c, r.now)
                    elif kind == TAKEN:
                        c.m.taken = r.taken
                        self.replies.taken(c, r.now, r.got, r.nev, r.used, True)
                    continue
                obj = owner(r.fd)
                if obj is lender:  # a write command's thread woke the loop
                    lender.woken()
                    continue
                if obj is None:
                    continue
                c = obj
                if c.armed:
                    self.synced(c)
                t = r.now
                if c.state == "open":
                    self.replies.readable(c, t)
                elif r.events & WRITABLE:
                    self._connected(c, t)
                    if c.entry is not None and c.state == "open" and not c.busy:
                        self._send(c, t)  # the rest of a poll, on a new connection
                    self._next(c, t)
