"""The connections of the one TCP loop (:mod:`pymb.logger.tcploop`):
:class:`Conn`, a bus's connection to its ``host:port`` and the polls waiting
for it (the loop's thread opens and closes them: :mod:`pymb.logger.tcpbase`),
:class:`Loan`, one lending of it to a write command, and :func:`fans_out`,
which buses the loop polls."""

from __future__ import annotations

import collections
import contextlib
import ipaddress
import socket
import threading
from dataclasses import dataclass, field
from typing import Any

from pymb._native.master import Master, PollTable
from pymb.client import unresolved
from pymb.client.address import is_mbaps
from pymb.logger.config import BusConfig
from pymb.logger.schedule import Backoff
from pymb.logger.tcpunits import Entry, PollRequest, Unit

__all__ = ["Conn", "Loan", "fans_out", "is_address", "look_up"]


class Loan:
    """One lending of a connection: asked, given (``fd``), given back."""

    def __init__(self) -> None:
        self.given = threading.Event()
        self.back = threading.Event()
        self.cancelled = False  #: the borrower stopped waiting before it was given
        self.fd = -1
        #: given: the transaction id of the borrower's first request (the polls'
        #: next one); given back: the one after its last (the polls go on from it)
        self.tid = 0


@dataclass(eq=False)
class Conn:
    """One bus: a connection to ``host:port`` and the polls waiting for it."""

    bus: BusConfig
    host: str
    port: int
    units: list[Unit]
    entries: list[Entry]
    pipeline: int
    sock: socket.socket | None = None
    state: str = "closed"  # closed, connecting, open
    opened_once: bool = False
    answered: bool = False  #: a reply came on this connection (it is worth reopening at once)
    retry_at: float = 0.0
    backoff: Backoff = field(default_factory=Backoff)
    deadline: float = 0.0
    waiting: collections.deque[Entry] = field(default_factory=collections.deque)
    entry: Entry | None = None  #: the poll under way
    todo: list[PollRequest] = field(default_factory=list)  #: its requests
    #: ``todo`` made ready for the master (each request's token its index)
    table: PollTable | None = None
    sent: int = 0  #: of ``todo``
    #: the stream's transactions (:class:`pymb._native.master.Master`): the
    #: requests in flight, ``todo[sent - in_flight:sent]`` (or some of them),
    #: and a reply cut short
    m: Master = field(default_factory=Master)
    #: the socket's SO_RCVLOWAT: while a poll's last requests are in flight,
    #: the bytes their replies take, so the loop wakes once for them all
    lowat: int = 1
    whole: bool = False  #: the poll under way went out at once, all of it
    look: int = 0  #: that poll's mark in the loop's heap of looks
    sent_at: float = 0.0  #: when the last requests of the poll under way went out
    took: float = 0.0  #: seconds a poll's replies took to come in full, of late
    unread: set[int] = field(default_factory=set)  #: items refused in this poll
    quiet_until: float = 0.0  #: a timed device's silence (turnaround, after_connect)
    last_end: float = 0.0
    #: (family, address) the host resolved to: resolved again only after a
    #: failed connect
    resolved: tuple[int, Any] | None = None
    #: a name lookup under way in a thread of its own (it may take seconds:
    #: the loop does not wait for it) and what it found (or why not)
    lookup: threading.Thread | None = None
    found: tuple[int, Any] | str | None = None
    #: requests sent on this connection (the replies to those not in flight came,
    #: but for the ``gave_up``)
    asked: int = 0
    #: requests given up on while in flight on this connection (a timeout, a
    #: poll failed by an exception): no reply to them came in time
    gave_up: int = 0
    #: the requests a connection of this device carries: the device closes it
    #: after that many replies, as it did twice in a row (0: no such limit)
    limit: int = 0
    closed_after: int = 0  #: the replies the last connection the device closed carried
    #: the poll under way while the connection is opened again for the rest of
    #: it (the device closes a connection after its replies); opened again so,
    #: the connection is the same device: what it taught is kept
    resume: Entry | None = None
    renew: bool = False  #: being opened again so (not after a failure)
    tell: bool = False  #: ... and the reconnect is an event (the way of working not yet known)
    loan: Loan | None = None  #: a write command's thread borrows it between polls (tcplend)
    index: int = -1  #: its place in the loop's C part (:class:`pymb._native.loop.Loop`)
    #: its polls are the C part's: a whole poll in flight, the next one the same
    #: requests at once (:meth:`TcpLoopBase.arm <pymb.logger.tcpbase.TcpLoopBase.arm>`),
    #: or a chain (:meth:`TcpLoopBase.chain <pymb.logger.tcpbase.TcpLoopBase.chain>`)
    armed: bool = False
    #: the chain the C part carries: the poll under way, then those waiting after it
    chain: collections.deque[Entry] = field(default_factory=collections.deque)

    @property
    def in_flight(self) -> int:
        """How many requests are in flight."""
        return self.m.in_flight

    @property
    def answered_here(self) -> int:
        """How many requests this connection carried the device answered
        (with its reply or an exception)."""
        return self.asked - self.m.in_flight - self.gave_up

    @property
    def busy(self) -> bool:
        """Whether a request is in flight."""
        return self.m.in_flight > 0

    def pending(self) -> list[PollRequest]:
        """The requests in flight, oldest first."""
        todo = self.todo
        return [todo[k] for k in self.m.pending()]

    def forget(self) -> None:
        """Nothing is in flight any more (replies still on their way are
        skipped as late ones by their transaction ids)."""
        self.gave_up += self.m.in_flight
        self.m.forget()
        self.whole = False

    def chain_of(self, e: Entry, now: float) -> list[Entry]:
        """The polls the loop's C part may carry from ``e``'s, under way here with
        its first requests just sent: it and the polls waiting after it, as
        long as each is :meth:`~pymb.logger.tcpunits.Entry.carriable` and its
        plan is the one its last poll had; none while anything else is to
        happen on the connection."""
        if (self.loan is not None or self.limit or self.unread or self.quiet_until > now
                or self.table is not e.table or self.todo is not e.specs
                or e.unit.planner.version != e.version or not e.carriable(now)):
            return []
        chain = [e]
        for w in self.waiting:  # (each planned as its last poll was: no planning here)
            if not w.specs or w.version != w.unit.planner.version or not w.carriable(now):
                break
            chain.append(w)
        return chain

    def wake_at(self, size: int) -> None:
        """Let the selector say readable once ``size`` bytes came (1: any)."""
        if size != self.lowat and self.sock is not None:
            with contextlib.suppress(OSError):  # (a socket gone bad: its next read says so)
                self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVLOWAT, size)
                self.lowat = size


def fans_out(bus: BusConfig) -> bool:
    """Whether ``bus`` is polled by the one loop: plain Modbus TCP (not
    Modbus/TCP Security, ``mbaps://``: its TLS is the client's) whose devices
    are each left offline for ``offline_retry`` after failures (a map of
    ``backoff = true``, the CoolPro's and the hub's, keeps a thread per bus)."""
    return (bus.tcp is not None and not is_mbaps(bus.tcp)
            and not any(d.map.timing.backoff for d in bus.devices))


def is_address(host: str) -> bool:
    """Whether ``host`` is an IP address (no name to look up)."""
    try:
        ipaddress.ip_address(host)
    except ValueError:
        return False
    return True


def look_up(c: Conn) -> None:
    """Resolve ``c``'s host into ``c.found`` (a name in a thread of its own)."""
    try:
        info = socket.getaddrinfo(c.host, c.port, type=socket.SOCK_STREAM)[0]
        c.found = (info[0], info[4])
    except (OSError, UnicodeError):
        c.found = unresolved(c.host) or f"cannot connect to {c.bus.endpoint}"

