"""The replies on the one TCP loop's connections (:mod:`pymb.logger.tcploop`):
:class:`TcpReplies`, which the loop owns, reads what came on a connection and hands it to the
connection's master (:class:`pymb._native.master.Master`, the C core's), which
matches each reply to its request by its transaction id, checks it and copies
its data into the poll's sample image, and keeps a reply cut short for the
next read. What is not such a reply comes back as an event: an exception
(the poller re-plans or fails the poll), a bad frame (the connection is
opened again), a late or foreign reply (skipped). What a reply, a refusal or
a loss does to the polls is the poller's (:class:`Polls`).
"""

from __future__ import annotations

import errno
import os
import socket
import time
from typing import Protocol

from pymb._native.master import BAD, EXCEPTION, NO_TOKEN, PollTable, ReadBuffer
from pymb.errors import ModbusError, ProtocolError
from pymb.logger.report import Report
from pymb.logger.schedule import TEXT
from pymb.logger.tcpconn import Conn
from pymb.logger.tcpunits import Entry, PollRequest, asked

__all__ = ["Polls", "TcpReplies"]

_PEEK = socket.MSG_PEEK


class Polls(Protocol):
    """What the replies do to the polls (:class:`pymb.logger.tcploop.TcpMapPoller`)."""

    report: Report  #: where the events go

    def lost(self, c: Conn, now: float, why: str, err: int | None) -> None:
        """``c``'s connection failed (``err``: its errno, if any)."""

    def progress(self, c: Conn, e: Entry, now: float) -> None:
        """Replies (or refusals) came for ``e``, the poll under way on ``c``."""

    def refused(self, c: Conn, e: Entry, spec: PollRequest, code: int, tid: int,
                now: float) -> None:
        """The device answered ``spec`` of ``e`` (sent as transaction ``tid``)
        with exception ``code``."""

    def failed(self, c: Conn, e: Entry, exc: ModbusError, now: float) -> None:
        """The poll of ``e`` failed with ``exc``."""

    def reopen(self, c: Conn, now: float) -> str:
        """Close ``c`` after a failure and open it again (when: as events say it)."""

    def again(self, c: Conn, e: Entry, now: float) -> PollTable | None:
        """The requests of ``e``'s next poll, to be framed as soon as the
        poll under way on ``c`` read every request (``None``: not so)."""

    def restarted(self, c: Conn, e: Entry, now: float) -> None:
        """``e``'s poll read every request, and the master framed the next
        one (:meth:`again`'s requests)."""


class TcpReplies:
    """The loop's reading side: ``polls`` says what a reply, an exception or
    a loss does to its polls."""

    def __init__(self, polls: Polls) -> None:
        self.polls = polls
        #: the one buffer every connection is read into (the loop's C part's too)
        self.rx = ReadBuffer()

    # -- reading -------------------------------------------------------------------------

    def _recv(self, c: Conn, sock: socket.socket, view: memoryview, size: int = 0,
              flags: int = 0) -> int:
        """``sock.recv_into``: the bytes read; 0 when there were none yet or
        the connection is lost (told here)."""
        try:
            got = sock.recv_into(view, size, flags)
        except BlockingIOError:
            return 0
        except OSError as err:
            self.polls.lost(c, time.monotonic(), os.strerror(err.errno or errno.ECONNRESET),
                            err.errno)
            return 0
        if not got:
            self.polls.lost(c, time.monotonic(), "the connection was closed by the device",
                            errno.ECONNRESET)
        return got

    def readable(self, c: Conn, now: float) -> None:
        """Read what came on ``c`` (open, or the connection is lost)."""
        sock = c.sock
        assert sock is not None
        rx = self.rx
        peek = c.lowat > 1  # woken for a whole poll's replies: looked at, dropped after
        got = self._recv(c, sock, rx.view, 0, _PEEK if peek else 0)
        if not got:
            return
        m = c.m
        e = c.entry
        if e is None:
            table = again = None
        else:
            table = c.table
            again = self.polls.again(c, e, now) if c.whole else None
        n, pos = m.take(rx, 0, got, table, again)
        if m.framed:  # the poll's last replies, and the next poll framed
            assert e is not None
            c.answered = True
            self.polls.restarted(c, e, now)
            if peek:
                self._drop(c, sock, got)
            return
        self.taken(c, now, got, n, pos, peek)

    def taken(self, c: Conn, now: float, got: int, n: int, pos: int, peek: bool) -> None:
        """``c``'s master took ``got`` bytes of :attr:`rx` (``pos`` of them
        used, ``n`` events, :attr:`Master.taken` replies) and framed no next
        poll: what they do to the poll (also after the loop's C part took
        them: :data:`pymb._native.loop.TAKEN`). ``peek``: they are still in
        the socket, to be dropped."""
        sock = c.sock
        assert sock is not None
        rx = self.rx
        m = c.m
        e = c.entry
        table = c.table if e is not None else None
        if not n and pos == got:  # replies only (or a part of one)
            if m.taken and e is not None:
                c.answered = True
                self.polls.progress(c, e, now)
            if peek:
                self._drop(c, sock, got)
            return
        answered = m.taken > 0
        events = [m.event(i) for i in range(n)]
        while pos < got and n and events[-1].kind != BAD:
            n, used = m.take(rx, pos, got - pos, table)
            answered = answered or m.taken > 0
            events += [m.event(i) for i in range(n)]
            pos += used
        for ev in events:
            if ev.kind == EXCEPTION:
                if e is not None and c.entry is e:
                    answered = True
                    self.polls.refused(c, e, c.todo[ev.token], ev.code, ev.tid, now)
            elif ev.kind == BAD:
                spec = c.todo[ev.token] if ev.token != NO_TOKEN and c.entry is e else None
                self._garbage(c, now, m.bad_frame(), spec)
                return
        if answered:
            c.answered = True
            if e is not None and c.entry is e:
                self.polls.progress(c, e, now)
        if peek:
            self._drop(c, sock, got)

    def _drop(self, c: Conn, sock: socket.socket, got: int) -> None:
        """Drop the ``got`` bytes taken from ``sock`` (looked at, not read),
        unless the connection went since (closed, or lent by the poll's end:
        the loan drained them, and a drop now could take the borrower's reply)."""
        loan = c.loan
        if c.sock is sock and (loan is None or not loan.given.is_set()):
            self._recv(c, sock, self.rx.view, got, socket.MSG_TRUNC)  # dropped unread

    def _garbage(self, c: Conn, now: float, got: bytes, spec: PollRequest | None = None) -> None:
        e = c.entry
        if e is not None:
            if spec is None:
                pending = c.pending()
                spec = pending[0] if pending else None
            exc = ProtocolError(f"{asked(spec, e.unit)} on {c.bus.endpoint}: the reply does "
                                f"not match the request (received {got.hex(' ').upper()})",
                                response=got)
            self.polls.failed(c, e, exc, now)
            c.entry = None
        else:  # between polls: the bus's event
            self.polls.report.bus_fault(
                c.bus.name, "unexpected bytes", "protocol",
                TEXT["stray"].format(endpoint=c.bus.endpoint, got=got.hex(" ").upper()))
        self.polls.reopen(c, now)
