"""The replies on the one TCP loop's connections (:mod:`pymb.logger.tcploop`):
:class:`TcpReplies` reads what came on a connection and hands each reply to
the poll under way.

A pipelined poll's replies, in the order its requests went out, are taken
by the C core in one call (:class:`pymb.logger.tcpfast.PollTable`): each
reply's first 9 bytes checked, its data bytes copied into the sample image.
Whatever else comes is told apart here, one reply at a time, as when one
request is out: a reply in another order (by its transaction id), a late
one (skipped), one that came before its request went out (skipped), an
exception, garbage (the connection is opened again), a part of a reply
(kept for the next read).
"""

from __future__ import annotations

import errno
import os
import queue
import socket
import threading
import time

from pymb.errors import ModbusError, ProtocolError
from pymb.logger.poller import Stats
from pymb.logger.tcpconn import Conn, TcpLoopBase, asked, sent_after, which
from pymb.logger.tcpfast import ReadBuffer
from pymb.logger.tcpunits import Entry, Spec, Unit
from pymb.store import Event, Sample

__all__ = ["TcpReplies"]


class TcpReplies(TcpLoopBase):
    """The loop's reading side; the poller (:class:`pymb.logger.tcploop.TcpMapPoller`)
    says what a reply, an exception or a loss does to its polls."""

    def __init__(self, out: queue.Queue[list[Sample | Event]], stop: threading.Event,
                 stats: Stats) -> None:
        super().__init__(out, stop, stats)
        self._rx = ReadBuffer()  #: the one buffer every connection is read into

    # -- what the poller does ------------------------------------------------------------

    def _lost(self, c: Conn, now: float, why: str, err: int | None) -> None:
        raise NotImplementedError

    def _send(self, c: Conn, now: float) -> None:
        raise NotImplementedError

    def _next(self, c: Conn, now: float) -> None:
        raise NotImplementedError

    def _done(self, c: Conn, e: Entry, now: float) -> None:
        raise NotImplementedError

    def _replied(self, c: Conn, e: Entry, now: float) -> None:
        raise NotImplementedError

    def _exception(self, c: Conn, e: Entry, spec: Spec, code: int, now: float) -> None:
        raise NotImplementedError

    def _failed(self, c: Conn, u: Unit, e: ModbusError) -> None:
        raise NotImplementedError

    def _requeue(self, c: Conn, e: Entry, now: float) -> None:
        raise NotImplementedError

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
            self._lost(c, time.monotonic(), os.strerror(err.errno or errno.ECONNRESET),
                       err.errno)
            return 0
        if not got:
            self._lost(c, time.monotonic(), "the connection was closed by the device",
                       errno.ECONNRESET)
        return got

    def _whole(self, c: Conn, sock: socket.socket, n: int, now: float) -> bool:
        """The ``n`` bytes looked at (left in the socket) are exactly the
        replies of the poll under way: the poll is done and the next one sent
        before they are dropped from the socket, so its requests carry their
        acknowledgement (reading them first makes the system send one of its
        own). False: they are to be read as usual."""
        t = c.fast
        k = c.fast_n
        if t is None or not k or c.sent != len(c.todo):
            return False
        first = c.sent - k
        if n != t.ends[c.sent] - t.ends[first]:
            return False
        taken, _ = t.take(first, k, (c.tid - k + 1) & 0xFFFF, self._rx, n)
        if taken != k:
            return False
        e = c.entry
        assert e is not None
        c.answered = True
        c.fast_n = 0
        c.took += (now - c.sent_at - c.took) / 8
        self._done(c, e, now)
        self._next(c, now)
        if c.sock is sock:
            self._recv(c, sock, self._rx.view, n, socket.MSG_TRUNC)  # dropped unread
        return True

    def _readable(self, c: Conn, now: float) -> None:
        sock = c.sock
        assert sock is not None
        rx = self._rx
        kept = len(c.rbuf)  # a part of a reply from the last read goes first
        if kept:
            rx.data[:kept] = c.rbuf
            got = self._recv(c, sock, rx.view[kept:])
        elif c.lowat > 1:  # woken for a whole poll's replies: looked at first
            got = self._recv(c, sock, rx.view, 0, socket.MSG_PEEK)
            if got and self._whole(c, sock, got, now):
                return
            if got:
                got = self._recv(c, sock, rx.view, got)  # the same bytes, read
        else:
            got = self._recv(c, sock, rx.view)
        if not got:
            return
        n = kept + got
        if kept:
            c.rbuf.clear()
        fresh = c.tid  # the last request sent before these bytes came: none later is answered
        pos = 0
        t = c.fast
        if t is not None and c.fast_n:  # the replies in the order sent, by the C core
            k = c.fast_n
            first, tid = c.sent - k, (c.tid - k + 1) & 0xFFFF
            taken, pos = t.take(first, k, tid, rx, n)
            if taken < k and pos < n and n - pos < t.sizes[first + taken] and (
                    n - pos < 9 or rx.data[pos:pos + 9] == ((tid + taken) & 0xFFFF).to_bytes(
                        2, "big") + c.todo[first + taken].head):
                c.rbuf += rx.view[pos:n]  # the rest of that reply is on its way
                pos = n
            if taken:
                e = c.entry
                assert e is not None
                c.answered = True
                c.fast_n = k - taken
                if c.sent < len(c.todo):
                    self._send(c, now)  # the next of a poll longer than the pipeline
                elif c.fast_n:
                    c.deadline = now + e.unit.timeout  # the rest are on their way
                    if c.lowat > 1:
                        c.wake_at(max(1, t.ends[c.sent] - t.ends[c.sent - c.fast_n]
                                      - len(c.rbuf)))
                else:
                    c.took += (now - c.sent_at - c.took) / 8
                    self._done(c, e, now)
                    self._next(c, now)
            if pos == n or c.sock is not sock:
                return
        data = bytes(rx.view[pos:n])
        pos, n = 0, len(data)
        inflight = c.inflight
        while n - pos >= 9:
            if inflight:
                i = 0 if data[pos:pos + 9] == inflight[0][0] else which(inflight, data, pos, 9)
                if i >= 0 and c.tid != fresh and sent_after(inflight[i][0], fresh):
                    i = -1  # a reply that came before its request went out: skipped
                if i >= 0:  # (a server may answer pipelined requests in any order)
                    spec = inflight[i][1]
                    size = spec.size
                    if n - pos < size:
                        break
                    e = c.entry
                    assert e is not None
                    if spec.bits:
                        spec.place(e.image, data, pos)
                    else:
                        off = spec.offset
                        e.image[off:off + size - 9] = data[pos + 9:pos + size]
                    pos += size
                    del inflight[i]
                    c.answered = True
                    if inflight and c.sent == len(c.todo) and not e.unit.timed:
                        c.deadline = now + e.unit.timeout
                        continue  # the rest of this poll's replies are on their way
                    self._replied(c, e, now)
                    if c.sock is not sock:
                        return
                    continue
            used = self._odd(c, data, pos, now, fresh)
            if used < 0 or c.sock is not sock:
                return
            if used == 0:
                break
            pos += used
        if pos < n:
            c.rbuf += data[pos:]

    def _odd(self, c: Conn, data: bytes, pos: int, now: float, fresh: int) -> int:
        """A reply that is not the expected one: a late one (another
        transaction id: skipped), an exception, or garbage (the connection is
        dropped: -1). Returns the bytes used (0: wait for more)."""
        if data[pos + 2:pos + 4] != b"\x00\x00":
            self._garbage(c, now, data[pos:pos + 9])
            return -1
        length = int.from_bytes(data[pos + 4:pos + 6], "big")
        if not 3 <= length <= 254:
            self._garbage(c, now, data[pos:pos + 9])
            return -1
        if len(data) - pos < 6 + length:
            return 0
        i = which(c.inflight, data, pos, 2)
        if i < 0 or (c.tid != fresh and sent_after(c.inflight[i][0], fresh)):
            return 6 + length  # the late reply of a request that timed out, or an early one
        head, spec = c.inflight[i]
        e = c.entry
        assert e is not None
        if data[pos + 6] == head[6] and data[pos + 7] == head[7] | 0x80 and length == 3:
            del c.inflight[i]
            c.answered = True
            self._exception(c, e, spec, data[pos + 8], now)
            return 9
        self._garbage(c, now, data[pos:pos + 6 + length], spec)
        return -1

    def _garbage(self, c: Conn, now: float, got: bytes, spec: Spec | None = None) -> None:
        e = c.entry
        if e is not None:
            spec = spec or (c.inflight[0][1] if c.inflight else None)
            exc = ProtocolError(f"{asked(spec, e.unit)} on {c.bus.endpoint}: the reply does "
                                f"not match the request (received {got.hex(' ').upper()})",
                                response=got)
            self._failed(c, e.unit, exc)
            self._requeue(c, e, now)
            c.entry = None
        else:  # between polls: the bus's event
            self.stats.fault(c.bus.name, f"bus {c.bus.name}: unexpected bytes")
            self._event(c, "protocol", f"{c.bus.endpoint}: bytes no request asked for "
                        f"(received {got.hex(' ').upper()})")
        self._reopen(c, now)
