"""The one TCP loop's thread (:mod:`pymb.logger.tcploop`): :class:`TcpLoopBase`,
the part that opens, closes and reopens its connections (:class:`~pymb.logger.tcpconn.Conn`:
non-blocking connects under one selector, the bus's doubling backoff, the connect and
reconnect events), hands the polls of the armed ones to its C part and back, and hands
samples and events to the writer (:class:`~pymb.logger.report.Report`)."""

from __future__ import annotations

import contextlib
import errno
import heapq
import math
import os
import queue
import socket
import threading
import time
from collections.abc import Iterable
from itertools import compress

from pymb._native.loop import GAP, Loop, Times
from pymb._native.master import PollTable, ReadBuffer
from pymb.logger.report import Report
from pymb.logger.schedule import BATCH_AGE, BATCH_MAX, TEXT, reappeared
from pymb.logger.stats import Stats
from pymb.logger.tcpcarry import Carried
from pymb.logger.tcpconn import Conn, is_address, look_up
from pymb.logger.tcpsel import READ, WRITE, Selector
from pymb.logger.tcpunits import Entry
from pymb.store import Event, Sample
from pymb.store.block import PollBlock, poll_sample

__all__ = ["TcpLoopBase"]


class TcpLoopBase(threading.Thread):
    """The loop's thread: its connections (:attr:`conns`), its selector, and
    the list of samples and events it hands to the writer on ``out``.

    Its C part (:attr:`cloop`, made by :meth:`start_loop` once the
    connections are known) waits on the selector's epoll and carries the
    polls of the *armed* connections itself: a connection whose whole poll
    is in flight and whose next poll is the same requests at once (flat out,
    nothing else waiting for it), or whose poll under way has others due
    after it (a *chain*, :meth:`chain`: devices behind one gateway read on a
    schedule, each poll read in C and the next one sent at once). It is
    armed after such a poll went out (:meth:`arm`) and taken back
    (:meth:`disarm`) whenever anything else is to happen on it: a poll that
    falls due, a loan, a deadline, a close; the C part hands it back itself
    for anything but a clean poll, and at a chain's end."""

    def __init__(self, out: queue.Queue[list[Sample | Event | PollBlock]], stop: threading.Event,
                 stats: Stats) -> None:
        super().__init__(name="pymb-tcp", daemon=True)
        self.out = out
        self.stop_event = stop
        self.stats = stats
        self.conns: list[Conn] = []
        self._sel = Selector()
        self.report = Report(out, stats)
        self._soonest = 0.0  #: the first deadline of a request or a connect (a sweep then)
        self.cloop: Loop | None = None  #: the C part (:meth:`start_loop`)
        self._block = memoryview(b"")  #: its block (the images of the polls it carried)
        self._seq = 0
        #: a heap of (when, seq, connection): a poll waiting for all of its
        #: replies at once (the connection's ``look`` is its seq), read as they
        #: come from then on
        self._looks: list[tuple[float, int, Conn]] = []
        #: what the armed connections' polls give the writer (made with the C part)
        self._carry = Carried(0, self.report, stats)
        self._polls: list[tuple[Conn, Entry]] = []  #: by :attr:`Entry.id`: its connection
        self._unarmed: list[bool] = []  #: by connection index: not armed
        self._armed_due = 0.0  #: no armed connection needs a sweep before (:meth:`sweeping`)
        self.loans = 0  #: loans asked (a borrower's thread counts them)
        self._loans_seen = 0  #: ... as of the last sweep of every connection

    def start_loop(self, rx: ReadBuffer, look_min: float) -> Loop:
        """The C part over :attr:`conns` (each one's :attr:`Conn.index` set),
        looking at replies in ``rx``; looks of at least ``look_min`` seconds.
        One wait of it carries a list's worth of polls for the writer
        (:data:`~pymb.logger.schedule.BATCH_MAX`, :data:`~pymb.logger.schedule.BATCH_AGE`):
        their images copied to its block, the loop woken once for them all,
        and the C part itself woken once for several replies (:data:`~pymb._native.loop.GAP`)."""
        for i, c in enumerate(self.conns):
            c.index = i
            for e in c.entries:
                e.id = len(self._polls)
                self._polls.append((c, e))
        self._carry = Carried(len(self._polls), self.report, self.stats)
        self._unarmed = [True] * len(self.conns)
        image = max((len(e.image) for c in self.conns for e in c.entries), default=0)
        self.cloop = Loop(self._sel.fileno(), len(self.conns), rx, look_min, polls=BATCH_MAX,
                          block=BATCH_MAX * max(image, 1), hold=BATCH_AGE, gap=GAP)
        self._block = memoryview(self.cloop.block)
        return self.cloop

    def arm(self, c: Conn, t: PollTable, timeout: float, look_at: float) -> None:
        """``c``'s whole poll ``t`` just went out, and its next one is the same
        requests at once: the C part carries its polls from now on."""
        cloop = self.cloop
        if cloop is not None:
            assert c.entry is not None
            cloop.arm(c.index, c.m, t, timeout, c.took, c.sent_at, look_at, c.entry.id)
            self._armed([c.entry], c)

    def again(self, c: Conn, e: Entry, now: float) -> PollTable | None:
        """The requests of ``e``'s next poll if it follows the one under way
        at once, the same requests sent whole again (flat out, no other poll
        of the connection waiting, the plan as it was): the master frames
        them as soon as this poll's replies are in (the poller's ``restarted``)."""
        slot = e.slot
        planner = e.unit.planner
        if (slot.interval or slot.once or c.waiting or c.loan is not None or c.limit
                or c.unread or not c.whole or c.table is not e.table or c.todo is not e.specs
                or c.quiet_until > now or now < slot.health.retry_at
                or planner.version != e.version or planner.retry_at != math.inf):
            return None
        return e.table

    def chain(self, c: Conn, chain: list[Entry], now: float, look_at: float) -> None:
        """``c``'s poll under way, the first of ``chain``, just sent its first
        requests at ``now``, and the others wait after it at the front of
        ``c.waiting``: the C part carries them one after another from now on."""
        cloop = self.cloop
        if cloop is not None and not c.armed:
            polls = []
            for e in chain:
                assert e.table is not None  # (planned: Entry.requests)
                polls.append((e.table, e.unit.timeout, e.id))
            cloop.chain(c.index, c.m, polls, c.pipeline, c.sent, c.took, now, c.lowat, look_at)
            c.chain.extend(chain)
            self._armed(chain, c)

    def _armed(self, polls: list[Entry], c: Conn) -> None:
        c.armed = True
        c.look = 0  # (its look is the C part's)
        for e in polls:
            self._carry.arm(e.id, e, c.bus.name)
        self._unarmed[c.index] = False
        self._armed_due = min(self._armed_due, c.deadline)

    def look(self, c: Conn, at: float) -> None:
        """``c``'s whole poll in flight is read as its replies come from ``at`` on."""
        self._seq += 1
        c.look = seq = self._seq
        heapq.heappush(self._looks, (at, seq, c))

    def looks_due(self, now: float) -> list[Conn]:
        """The connections whose whole poll's look is due by ``now`` (to be
        read as their replies come)."""
        looks = self._looks
        due = []
        while looks and looks[0][0] <= now:
            _, seq, c = heapq.heappop(looks)
            if c.look == seq and c.busy and c.lowat > 1:
                due.append(c)
        return due

    def synced(self, c: Conn) -> None:
        """``c`` is no longer armed (the C part handed it back, or the loop
        takes it): a whole poll in flight gets its look."""
        got = self.disarm(c)
        if got is not None and c.busy and c.lowat > 1:
            self.look(c, got.look_at)

    def sample(self, c: Conn, e: Entry, now: float) -> None:
        """A poll of ``e`` read every request at ``now``: its sample (the
        connection is idle)."""
        u = e.unit
        c.entry = None
        c.whole = False
        unread = e.unsupported()
        if c.unread:
            unread = (unread | c.unread) & e.decode.items
        s, reading = poll_sample(u.info, time.time(), now, e.decode, bytes(e.image), unread)
        report = self.report
        report.sample(s)
        report.answered(c.bus.name, u.health, u.info, reading.unsupported)

    def carried(self, c: Conn, now: float) -> None:
        """The C part read ``c``'s poll in full at ``now`` and the next one
        did not go out whole: the poll's sample, of its own image."""
        e = c.entry
        assert e is not None
        self.sample(c, e, now)
        c.entry = e
        c.whole = True

    def carried_block(self, done: list[int], at: list[float], offs: list[int]
                      ) -> list[tuple[Conn, Entry, float]]:
        """The C part read the polls ``done`` (:attr:`Entry.id`) in full at ``at``, their
        images at ``offs`` in its block: one :class:`~pymb.store.block.PollBlock` for the
        writer (:class:`~pymb.logger.tcpcarry.Carried`). Returns the polls of chains read
        (each connection's next poll is under way, or none): their slots are the caller's."""
        wall, mono = time.time(), time.monotonic()
        self.report.block(self._carry.block(done, at, offs, self._block, wall - mono))
        read = []
        for j, i in enumerate(done):
            c, e = self._polls[i]
            if c.chain:  # (flat out: the same poll again)
                c.chain.popleft()
                c.answered = True
                read.append((c, e, at[j]))
                if c.chain:
                    c.entry = nxt = c.chain[0]
                    if c.waiting[0] is nxt:  # (it always is: a poll queued meanwhile disarms)
                        c.waiting.popleft()
                    else:
                        c.waiting.remove(nxt)
                    nxt.queued = False
                    c.todo, c.table = nxt.specs, nxt.table
                else:
                    c.entry = None
        return read

    def disarm(self, c: Conn) -> Times | None:
        """``c`` is the loop's again (``c.armed`` or not: the C part may have
        handed it back): its poll's times and counts back in ``c``; None if
        it was not armed."""
        if not c.armed or self.cloop is None:
            return None
        c.armed = False
        for e in c.chain or (c.entry,):
            if e is not None:
                self._carry.disarm(e.id)
        self._unarmed[c.index] = True
        got = self.cloop.disarm(c.index)
        c.took, c.sent_at, c.deadline = got.took, got.sent_at, got.deadline
        c.asked += got.asked
        if c.chain:  # the poll under way (the others wait their turn in c.waiting)
            c.chain.clear()
            c.sent, c.lowat, c.whole = got.sent, got.lowat, 1 < len(c.todo) <= c.pipeline
        elif got.lowat:  # (a chain read to its end)
            c.lowat, c.whole = got.lowat, False
        return got

    def sweeping(self, now: float, tick: float) -> Iterable[Conn]:
        """The connections a sweep at ``now`` looks at: all when an armed one may need it (a
        deadline within ``tick``, a loan asked since), else those not armed (flat out, reading
        100 armed ones' fields missed the cache for about 70 us a sweep)."""
        loans = self.loans
        if now + tick < self._armed_due and loans == self._loans_seen:
            return compress(self.conns, self._unarmed)
        self._loans_seen, self._armed_due = loans, float("inf")  # (:meth:`armed_on` sets it)
        return self.conns

    def armed_on(self, c: Conn, now: float, tick: float) -> bool:
        """Armed ``c`` in a sweep at ``now``: True while its polls stay the C part's (no loan
        asked, its poll's deadline, the C part's read as it nears, not within ``tick``), else
        it is taken back (:meth:`synced`)."""
        if c.loan is None:  # (a loan waits for the end of the poll under way)
            if now + tick >= c.deadline:
                assert self.cloop is not None
                c.deadline = self.cloop.deadline(c.index)
                if now < c.deadline < self._soonest:  # a poll in flight: a sweep then
                    self._soonest = c.deadline
            if now < c.deadline:
                self._armed_due = c.deadline if c.deadline < self._armed_due else self._armed_due
                return True
        self.synced(c)
        return False

    # -- hand-over -----------------------------------------------------------------------

    def flush(self) -> None:
        """Hand what was read since the last list to the writer."""
        self.report.flush()

    def take_unflushed(self) -> list[Sample | Event | PollBlock]:
        """What this poller read but has not handed over (the writer takes it
        when the poller is left behind at stop)."""
        return self.report.take()

    # -- connections ---------------------------------------------------------------------

    def _connect(self, c: Conn, now: float) -> None:
        if c.resolved is None:
            if is_address(c.host):  # no lookup
                look_up(c)
            else:
                if c.lookup is None:  # a name: looked up aside, the sweeps ask again
                    c.found = None
                    c.lookup = threading.Thread(target=look_up, args=(c,), daemon=True,
                                                name="pymb-tcp-lookup")
                    c.lookup.start()
                if c.lookup.is_alive():
                    return
                c.lookup = None
            if not isinstance(c.found, tuple):
                self._not_open(c, now, c.found or f"cannot connect to {c.bus.endpoint}")
                return
            c.resolved = c.found
        family, addr = c.resolved
        try:
            s = socket.socket(family, socket.SOCK_STREAM)
        except OSError as err:
            self._not_open(c, now, f"cannot connect to {c.bus.endpoint}: {err.strerror}")
            return
        s.setblocking(False)
        s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        c.asked = c.gave_up = 0
        rc = s.connect_ex(addr)
        if rc not in (0, errno.EINPROGRESS):
            s.close()
            self._not_open(c, now, f"cannot connect to {c.bus.endpoint}: {os.strerror(rc)}")
            return
        c.sock, c.state, c.lowat = s, "connecting", 1
        c.deadline = now + c.bus.timeout
        self._soonest = min(self._soonest, c.deadline)
        self._sel.register(s, WRITE, c)
        if self.cloop is not None:
            self.cloop.bind(c.index, s.fileno())

    def _not_open(self, c: Conn, now: float, why: str) -> None:
        c.resolved = None
        wait = c.backoff.take()
        self.report.not_open(c.bus.name, why, wait)
        c.retry_at = now + wait

    def _connected(self, c: Conn, now: float) -> None:
        assert c.sock is not None
        err = c.sock.getsockopt(socket.SOL_SOCKET, socket.SO_ERROR)
        if err:
            self._close(c)
            self._not_open(c, now, f"cannot connect to {c.bus.endpoint}: {os.strerror(err)}")
            return
        c.state = "open"
        c.answered = False
        self._sel.modify(c.sock, READ, c)
        report = self.report
        report.opened(c.bus.name)
        wait = max(u.config.map.timing.after_connect for u in c.units)
        c.quiet_until = now + wait
        if c.renew:
            # opened again because the device closes a connection after its
            # replies: the same device, what it taught kept, the poll under
            # way goes on, "once after connect" groups are not read again
            c.entry, c.resume, c.renew = c.resume, None, False
            c.backoff.reset()
            if c.tell:
                c.tell = False
                report.reconnected(c.bus.name, c.bus.endpoint)
            return
        if c.opened_once:
            report.reconnected(c.bus.name, c.bus.endpoint)
        else:
            report.connected(c.bus.name, c.bus.endpoint, len(c.units))
        c.opened_once = True
        # a new connection may be a new device: forget what the last one taught
        for u in c.units:
            u.planner.forget()
        reappeared(e.slot for e in c.entries)
        # the polls waiting, in the order of the devices and groups
        c.waiting.clear()
        for e in c.entries:
            if e.queued or e.slot.interval == 0:
                e.queued = True
                c.waiting.append(e)

    def reopen(self, c: Conn, now: float) -> str:
        """Close ``c`` after a failure on it: opened again at once when it
        carried a reply, else after the bus's doubling backoff (a device
        that accepts and drops every connection is not hammered). Returns
        the retry as an event says it ("" when at once)."""
        self._close(c)
        if c.answered:
            c.backoff.reset()
            c.retry_at = now
            return ""
        wait = c.backoff.take()
        c.retry_at = now + wait
        return TEXT["retrying"].format(why="", wait=wait)

    def _closed_after_replies(self, c: Conn, now: float) -> None:
        """The device closed the connection after it answered (some devices
        and gateways take one request a connection): the requests it did
        not answer go out again on a new connection, at once, and the poll
        under way goes on there. Closed after as many replies twice in a
        row, that many is what a connection carries from then on
        (:attr:`Conn.limit`): the loop opens the next one itself."""
        answered = c.answered_here
        replies = f"{answered} repl{'y' if answered == 1 else 'ies'}"
        c.tell = False
        if answered == c.closed_after and not c.limit:
            c.limit = answered
            self.report.event(c.bus.name, "reconnect", TEXT["closes"].format(
                endpoint=c.bus.endpoint, replies=replies, n=answered))
        elif not c.limit:  # not (yet) its way of working: said, as a loss is
            self.report.bus_fault(c.bus.name, "the connection was closed", "connection",
                                  TEXT["closed"].format(endpoint=c.bus.endpoint,
                                                        replies=replies))
            c.tell = True
        c.closed_after = answered
        if c.entry is not None:  # what is in flight goes out again
            pending = c.pending()
            if pending:
                gone = {id(s) for s in pending}
                done = [s for s in c.todo[:c.sent] if id(s) not in gone]
                c.todo = [*done, *pending, *c.todo[c.sent:]]
                c.sent = len(done)
                c.table = c.entry.table_of(c.todo)
        self._renew(c, now)

    def _renew(self, c: Conn, now: float) -> None:
        """Open ``c`` again for the rest of the poll under way (and the
        next ones), the device being the same (:meth:`_closed_after_replies`)."""
        c.resume, c.renew = c.entry, True
        self._close(c)
        c.retry_at = now
        self._connect(c, now)

    def _close(self, c: Conn) -> None:
        self.disarm(c)
        if c.sock is not None:
            with contextlib.suppress(KeyError, ValueError):
                self._sel.unregister(c.sock)
            if self.cloop is not None:
                self.cloop.unbind(c.sock.fileno())
            c.sock.close()
        c.sock, c.state = None, "closed"
        c.forget()
        c.m.reset()  # (a reply cut short is dropped with the stream)
        c.entry = None
