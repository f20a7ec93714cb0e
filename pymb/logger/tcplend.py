"""A poll connection of the one TCP loop lent to another thread between two
polls: :class:`Lender`, which the loop (:class:`~pymb.logger.tcploop.TcpMapPoller`)
owns as ``lender``.

A write command for a device on the loop goes over the connection its polls
use, so a gateway that takes one connection, or a device that serves one
master, sees one master. The command's thread asks for the connection
(:meth:`Lender.borrow`); the loop hands it over when no poll is under way on
it (before it starts the next one, never between a poll's requests): it stops
watching the socket, drops whatever late bytes wait in it, and gives its
descriptor. The thread writes and reads back over a duplicate of it, then
gives it back (:meth:`Lender.give_back`), and the loop's polls go on. The
polls that fall due meanwhile wait (a slot that passes is counted skipped).
"""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from collections.abc import Callable

from pymb.errors import ModbusConnectionError, ModbusTimeout
from pymb.logger.tcpconn import Conn, Loan
from pymb.logger.tcpsel import READ, Selector

__all__ = ["Lender"]


class Lender:
    """The loop's side and the borrower's side of lending a poll connection.

    ``sel`` is the loop's selector: the lender registers its wake-up socket
    in it (with itself as the key's data: the loop calls :meth:`woken` when
    that key is ready) and takes a lent connection's socket out of it.
    ``sweep_now`` tells the loop to look at its idle connections at once
    (where it calls :meth:`lend`)."""

    def __init__(self, sel: Selector, sweep_now: Callable[[], None]) -> None:
        self._sel = sel
        self._sweep_now = sweep_now
        self._loan_lock = threading.Lock()
        #: written to by a borrower to wake the loop's select at once
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._wake_w.setblocking(False)
        sel.register(self._wake_r, READ, self)

    def woken(self) -> None:
        """The loop: a borrower woke the select (its byte is dropped)."""
        with contextlib.suppress(OSError):
            self._wake_r.recv(64)

    def close(self) -> None:
        """The loop ends: the wake-up socket pair is closed."""
        for s in (self._wake_r, self._wake_w):
            s.close()

    def _wake(self) -> None:
        self._sweep_now()
        with contextlib.suppress(OSError):
            self._wake_w.send(b"\0")

    # -- the borrower's side (any thread) ---------------------------------------------

    def borrow(self, c: Conn, timeout: float) -> Loan:
        """Wait until the loop lends ``c`` (no poll under way on it); the
        loan (its socket's descriptor, the transaction id its first request
        takes). Raises :class:`~pymb.ModbusTimeout` when it is
        not lent within ``timeout`` seconds, :class:`~pymb.ModbusConnectionError`
        while it is not open."""
        deadline = time.monotonic() + timeout
        while c.loan is not None:  # the last loan is being taken back
            if time.monotonic() > deadline:
                raise ModbusTimeout(f"{c.bus.endpoint}: the poll connection was not free "
                                    f"within {timeout:g} s", port=c.bus.endpoint)
            time.sleep(0.002)
        if c.state != "open":
            raise ModbusConnectionError(f"{c.bus.endpoint}: not connected now "
                                        f"({c.state}): nothing was sent", port=c.bus.endpoint)
        loan = Loan()
        c.loan = loan
        self._wake()
        if loan.given.wait(max(0.0, deadline - time.monotonic())):
            return loan
        with self._loan_lock:
            if not loan.given.is_set():
                loan.cancelled = True
                self._wake()
                raise ModbusTimeout(f"{c.bus.endpoint}: the poll connection was not free "
                                    f"within {timeout:g} s", port=c.bus.endpoint)
        return loan

    def give_back(self, c: Conn, tid: int | None = None) -> None:
        """The borrower is done with ``c``: the loop's polls go on, from
        transaction id ``tid`` (the one after the borrower's last; None: as
        they were)."""
        loan = c.loan
        if loan is not None:
            if tid is not None:
                loan.tid = tid
            loan.back.set()
            self._wake()

    # -- the loop's side ------------------------------------------------------------

    def lend(self, c: Conn) -> bool:
        """On an idle connection with a loan asked for (the loop's thread):
        lend it, or take it back; True while it is lent (no poll starts)."""
        loan = c.loan
        assert loan is not None
        if loan.back.is_set() or loan.cancelled:  # taken back
            c.loan = None
            if loan.given.is_set() and not c.busy:  # (no late borrower's reply is a poll's)
                c.m.next_tid = loan.tid
            if loan.given.is_set() and c.sock is not None and c.state == "open":
                with contextlib.suppress(KeyError, ValueError, OSError):
                    self._sel.register(c.sock, READ, c)
            return False
        if loan.given.is_set():
            return True
        if c.state != "open" or c.sock is None or c.entry is not None or c.busy or c.m.kept:
            return False  # (a late reply cut short: the loop sorts its stream out first)
        with self._loan_lock:
            if loan.cancelled:
                c.loan = None
                return False
            c.wake_at(1)
            sock = c.sock
            with contextlib.suppress(KeyError, ValueError):
                self._sel.unregister(sock)
            for _ in range(64):  # late replies of polls given up: not the borrower's
                try:
                    if not sock.recv(4096):
                        break
                except OSError:
                    break
            loan.fd = sock.fileno()
            loan.tid = c.m.next_tid  # (a poll given up on: its late reply is no answer)
            loan.given.set()
        return True
