"""The I/O of ``pymb log``'s one Modbus TCP loop, flat out and in chains, in C
(``csrc/pymb_loop.h``): :class:`Loop`.

One :meth:`Loop.wait` waits on the loop's epoll and, for each *armed*
connection whose whole poll came back, takes its replies into the poll's
image with the connection's :class:`~pymb._native.master.Master`, sends the
next poll (the same requests, framed in the same step) and drops the replies
from the socket: the poll's id is in :attr:`Loop.done`. A connection armed
with a chain (:meth:`Loop.chain`: the polls due one after another on it, of
several devices) has each poll's replies taken as they come, its requests
sent a window at a time, the next poll sent as soon as one is read, until
the last (:data:`END`). Everything else comes back for the loop
(:mod:`pymb.logger.tcploop`, and the bench's bare loop :mod:`pymb.bench.fanout`) to do as it
does it in Python: a socket ready that is not armed, or whose bytes are not just its poll's
replies (:data:`READY`, nothing read), a take that is not the poll's clean end
(:data:`TAKEN`: the master's events, the bytes in the loop's receive buffer),
a poll slower than its look (:data:`LOOK`). The loop arms a connection while
its next poll follows at once (the same requests, or the next of a chain), and takes it back
(:meth:`Loop.disarm`) as soon as that is no longer so.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, NamedTuple

from pymb._native.master import Master, PollTable, ReadBuffer
from pymb._pymb_cffi import ffi, lib

__all__ = ["DONE", "END", "GAP", "LOOK", "LOOK_MIN", "NO_CONN", "READY", "TAKEN", "UNSENT", "Loop",
           "Times", "look"]

READY: int = lib.PYMBI_LOOP_READY  #: a socket is ready, nothing read (``events``: its mask)
DONE: int = lib.PYMBI_LOOP_DONE  #: a poll read in full, the next one not all sent (``sent``)
TAKEN: int = lib.PYMBI_LOOP_TAKEN  #: replies taken, not the poll's clean end (``nev`` events)
LOOK: int = lib.PYMBI_LOOP_LOOK  #: a poll slower than its look: nothing read
END: int = lib.PYMBI_LOOP_END  #: a chain's last poll read (in :attr:`Loop.done`)
#: a chain's poll read (in :attr:`Loop.done`), the next one not all sent (``sent``)
UNSENT: int = lib.PYMBI_LOOP_UNSENT
NO_CONN: int = lib.PYMBI_LOOP_NO_CONN  #: a READY socket that is no connection of the loop

# The tuning ``pymb log`` runs the loop with (and the bench's bare loop, to be its floor):
#: a poll's replies have twice the time they took of late (at least this many
#: seconds) to come in full before they are read as they come (an exception
#: reply is shorter than the reply it stands for)
LOOK_MIN = 0.002
#: while a wait holds the polls it carried, it sleeps this share of the
#: fastest armed poll's reply time before it looks again: one wake (a context
#: switch, as much CPU as a poll's Python) then takes the replies of several
#: polls, each poll's next one sent later by at most this share of its
#: replies' time
GAP = 1 / 16


def look(took: float, timeout: float) -> float:
    """How long a poll's replies have to come in full before they are read
    as they come: twice the time they took of late (``took``), at least
    :data:`LOOK_MIN`, at most a quarter of the ``timeout`` (the C loop's own
    rule for the polls it carries)."""
    # (conditional expressions: the builtins min and max parse keywords, per poll)
    t = 2 * took if 2 * took > LOOK_MIN else LOOK_MIN
    most = timeout / 4
    return t if t < most else most

_RECORDS = 256  #: records one wait writes at most
_wait = lib.pymbi_loop_wait
_unpack = ffi.unpack


class Times(NamedTuple):
    """An armed connection's poll as the C loop leaves it when disarmed."""

    took: float  #: seconds the replies took, of late
    sent_at: float  #: when the poll in flight went out
    look_at: float  #: when it is read as its replies come
    deadline: float  #: when it times out
    asked: int  #: requests the C loop sent since it was armed
    sent: int  #: a chain: requests of that poll sent
    lowat: int  #: a chain: the socket's ``SO_RCVLOWAT`` as the C loop left it


class Loop:
    """The C loop over the epoll ``epfd`` and ``n`` connections (by index);
    ``rx`` is where it looks at replies (a :data:`TAKEN` record's bytes stay
    there); a look is twice the replies' time, at least ``look_min`` seconds,
    at most a quarter of the timeout. A wait carries at most ``polls`` polls;
    with a ``block`` of that many bytes each poll's image is copied there, and
    a wait goes on carrying for ``hold`` seconds after its first poll read,
    sleeping ``gap`` times the fastest armed poll's reply time before each
    look (``csrc/pymb_loop.h``)."""

    __slots__ = ("_at_c", "_block_c", "_conns", "_done_c", "_held", "_lp", "_off_c", "_out", "_rx",
                 "_slots", "block", "done", "done_at", "done_off", "now", "recs")

    def __init__(self, epfd: int, n: int, rx: ReadBuffer, look_min: float, *,
                 polls: int = _RECORDS, block: int = 0, hold: float = 0.0,
                 gap: float = 0.0) -> None:
        self._conns: Any = ffi.new("pymbi_lconn[]", max(n, 1))
        #: an armed connection's master and poll table(s), kept alive while C points into them
        self._held: list[tuple[Any, ...] | None] = [None] * max(n, 1)
        self._slots: Any = ffi.new("int32_t[]", 0)
        self._out: Any = ffi.new("uint8_t[]", lib.PYMBI_MASTER_FRAME * lib.PYMBI_MASTER_INFLIGHT)
        #: the records of the last :meth:`wait` (``recs[i].kind``, ``.conn``, ``.now``, ...)
        self.recs: Any = ffi.new("pymbi_lrec[]", _RECORDS)
        lp = self._lp = ffi.new("pymbi_loop *")
        lp.epfd = epfd
        lp.conns = self._conns
        lp.nconns = n
        lp.slot_cap = 0
        lp.rx = rx.c
        lp.rx_cap = len(rx.data)
        lp.out = self._out
        lp.out_cap = len(self._out)
        lp.look_min = look_min
        self._done_c: Any = ffi.new("uint32_t[]", polls)
        lp.done = self._done_c
        lp.done_cap = polls
        #: the images of the polls the last :meth:`wait` read (``block`` bytes:
        #: none, each poll's image read before the next wait)
        self.block = bytearray(block)
        self._block_c: Any = ffi.from_buffer("uint8_t[]", self.block) if block else ffi.NULL
        self._off_c: Any = ffi.new("uint32_t[]", polls) if block else ffi.NULL
        self._at_c: Any = ffi.new("double[]", polls) if block else ffi.NULL
        lp.block = self._block_c
        lp.block_cap = block
        lp.done_off = self._off_c
        lp.done_at = self._at_c
        lp.hold = hold
        lp.gap = gap
        self._rx = rx
        #: the connections the last :meth:`wait` read a poll of and sent the
        #: next one whole (they stay armed), at most ``polls``: with a block, a
        #: connection may be in it more than once (the wait goes on carrying
        #: ``hold`` seconds after the first poll read)
        self.done: list[int] = []
        #: with a block: when each poll of :attr:`done` was read, and where its image
        #: starts in :attr:`block`
        self.done_at: list[float] = []
        self.done_off: list[int] = []
        #: when the last :meth:`wait` looked (``time.monotonic``'s clock)
        self.now = 0.0

    def bind(self, i: int, fd: int) -> None:
        """Connection ``i``'s socket is ``fd`` (from now until :meth:`unbind`)."""
        if not 0 <= i < self._lp.nconns:
            raise ValueError(f"connection {i} is not one of {self._lp.nconns}")
        cap = self._lp.slot_cap
        if fd >= cap:
            grown = ffi.new("int32_t[]", max(2 * cap, fd + 1, 64))
            ffi.memmove(grown, self._slots, 4 * cap)
            for k in range(cap, len(grown)):
                grown[k] = -1
            self._slots = grown
            self._lp.slot_of = grown
            self._lp.slot_cap = len(grown)
        self._slots[fd] = i
        self._conns[i].fd = fd

    def unbind(self, fd: int) -> None:
        """``fd`` is no connection's any more (it is being closed)."""
        if 0 <= fd < self._lp.slot_cap:
            self._slots[fd] = -1

    def arm(self, i: int, m: Master, t: PollTable, timeout: float, took: float,
            sent_at: float, look_at: float, poll: int | None = None) -> None:
        """Connection ``i`` has ``t``'s requests in flight on ``m``, all of
        them, sent at ``sent_at``; its next poll is the same requests, sent
        as soon as these are read (by :meth:`wait`, until :meth:`disarm`);
        each poll read is ``poll`` in :attr:`done` (None: ``i``)."""
        c = self._conns[i]
        c.m, c.ev, c.ev_cap = m.handles()
        c.reqs = t.rows
        c.n = t.n
        c.image = t.image_c
        c.image_len = t.image_len
        c.replies = t.ends[t.n]
        c.timeout = timeout
        c.took = took
        c.sent_at = sent_at
        c.look_at = look_at
        c.deadline = sent_at + timeout
        c.asked = 0
        c.id = i if poll is None else poll
        c.chain = ffi.NULL
        c.armed = 1
        self._held[i] = (m, t)

    def chain(self, i: int, m: Master, polls: Sequence[tuple[PollTable, float, int]],
              window: int, sent: int, took: float, sent_at: float, lowat: int,
              look_at: float) -> None:
        """Connection ``i`` has requests of the first of ``polls`` (each its
        table, timeout and id) in flight on ``m``, ``sent`` of them sent at
        ``sent_at`` (at most ``window`` in flight), its socket woken at
        ``lowat`` bytes (more than 1: all those replies, looked at from
        ``look_at``): the C loop carries the rest of it and the other polls,
        one after another, until the last is read (:data:`END`)."""
        c = self._conns[i]
        rows = ffi.new("pymbi_lpoll[]", len(polls))
        for k, (t, timeout, ident) in enumerate(polls):
            row = rows[k]
            row.reqs, row.n, row.image, row.image_len = t.rows, t.n, t.image_c, t.image_len
            row.timeout, row.id = timeout, ident
        first, timeout, ident = polls[0]
        c.m, c.ev, c.ev_cap = m.handles()
        c.reqs, c.n, c.image, c.image_len = first.rows, first.n, first.image_c, first.image_len
        c.timeout, c.id = timeout, ident
        c.replies = lowat if lowat > 1 else 0
        c.took, c.sent_at = took, sent_at
        c.look_at = look_at if lowat > 1 else math.inf
        c.deadline = sent_at + timeout
        c.asked = 0
        c.chain, c.nchain, c.at, c.sent = rows, len(polls), 0, sent
        c.window, c.lowat = window, lowat
        c.armed = 1
        self._held[i] = (m, [t for t, _, _ in polls], rows)

    def disarm(self, i: int) -> Times:
        """Connection ``i`` is the caller's again (also when :meth:`wait`
        handed it back): its poll's times and the requests sent since armed."""
        c = self._conns[i]
        c.armed = 0
        self._held[i] = None
        asked = int(c.asked)
        c.asked = 0
        chained = c.chain != ffi.NULL
        c.chain = ffi.NULL
        if not chained:
            return Times(c.took, c.sent_at, c.look_at, c.deadline, asked, 0, 0)
        return Times(c.took, c.sent_at, c.look_at, c.deadline, asked, c.sent, c.lowat)

    def deadline(self, i: int) -> float:
        """When armed connection ``i``'s poll in flight times out."""
        return self._conns[i].deadline  # type: ignore[no-any-return]

    def wait(self, timeout: float) -> int:
        """Wait up to ``timeout`` seconds (sooner for an armed connection's
        look): the records written to :attr:`recs`; :attr:`done` and
        :attr:`now` set (read from the C loop here, once a wait: each read
        of a cdata field costs a call's worth)."""
        lp = self._lp
        got: int = _wait(lp, timeout if timeout > 0 else 0.0, self.recs, _RECORDS)
        if got < 0:
            err = ffi.errno
            raise OSError(err, f"the TCP loop's wait failed (errno {err})")
        n = lp.ndone
        if n:
            self.done = _unpack(self._done_c, n)
            if self.block:
                self.done_at = _unpack(self._at_c, n)
                self.done_off = _unpack(self._off_c, n)
        else:
            self.done = []
        self.now = lp.now
        return got
