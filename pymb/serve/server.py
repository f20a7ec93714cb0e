"""The listening side of ``pymb serve``: an asyncio server whose connections
take requests with the C core, answer badly formed ones at once, and hand
the rest to the :class:`~pymb.serve.upstream.Upstream`, each reply going back
to the client that asked, with its own transaction id."""

from __future__ import annotations

import asyncio
import contextlib
import ssl
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import cast

from pymb._native.serve import BadFrame, exception_frame, mbap_frame, take_requests
from pymb.errors import InvalidArgument
from pymb.serve.pipeline import PipelinedUpstream
from pymb.serve.roles import CertificateError, role_of
from pymb.serve.upstream import EX_PATH, Upstream, reads_only

__all__ = ["ServeStats", "Server", "UnitMap"]

#: requests one client may have waiting upstream before its reading pauses
PENDING_PER_CLIENT = 16
EX_FUNCTION = 0x01  #: what an unauthorised request is answered (Modbus/TCP Security)
HANDSHAKE_TIMEOUT = 10.0  #: seconds a TLS client has to finish its handshake
_TLS_CHUNK = 16384  #: the largest TLS record's plaintext

#: OpenSSL's reasons a client's handshake fails for, in words (others as OpenSSL names them)
_REFUSED = {
    "PEER_DID_NOT_RETURN_A_CERTIFICATE": "the client gave no certificate",
    "WRONG_VERSION_NUMBER": "the client does not speak TLS (a plain Modbus TCP client?)",
    "HTTP_REQUEST": "an HTTP request, not TLS",
    "UNSUPPORTED_PROTOCOL": "the client offers only TLS versions below 1.2, which are refused",
    "NO_SHARED_CIPHER": "the client offers no cipher this server takes",
}


def refusal(e: ssl.SSLError) -> str:
    """Why a client's handshake failed, in words."""
    verify = getattr(e, "verify_message", None)
    if verify:
        return f"the client's certificate was refused: {verify}"
    return _REFUSED.get(e.reason or "") or str(e.reason or e)


@dataclass
class UnitMap:
    """Listen unit -> upstream unit. Units not named pass through unchanged
    (1..255); unit 0 (a broadcast, which no device answers) is refused with
    exception 0x0A."""

    routes: dict[int, int] = field(default_factory=dict)

    @classmethod
    def parse(cls, specs: list[str]) -> UnitMap:
        """From ``LISTEN=UPSTREAM`` texts (``--unit 1=17``)."""
        routes: dict[int, int] = {}
        for spec in specs:
            left, sep, right = spec.partition("=")
            if not sep or not left.strip().isdigit() or not right.strip().isdigit():
                raise InvalidArgument(f"--unit needs LISTEN=UPSTREAM (unit ids), got {spec!r}")
            a, b = int(left), int(right)
            for what, n in (("listen", a), ("upstream", b)):
                if not 1 <= n <= 255:
                    raise InvalidArgument(f"--unit {spec}: the {what} unit must be 1..255")
            if a in routes:
                raise InvalidArgument(f"--unit {a} is routed twice")
            routes[a] = b
        return cls(routes)

    def upstream(self, unit: int) -> int | None:
        """The upstream unit for listen ``unit`` (None: refused)."""
        if unit == 0:
            return None
        return self.routes.get(unit, unit)


@dataclass
class ServeStats:
    """What the server has done since it started."""

    connections: int = 0
    open: int = 0
    refused_connections: int = 0
    requests: int = 0
    replies: int = 0
    malformed: int = 0
    garbage: int = 0
    denied: int = 0
    tls_failures: int = 0
    #: reads left in the buffer of a client that had gone: never sent
    unsent: int = 0


class _Tls:
    """One connection's TLS, server side, over memory buffers: the bytes from
    the client go in, the plaintext comes out, and a failed handshake is an
    exception this connection can say in one line."""

    def __init__(self, ctx: ssl.SSLContext) -> None:
        self._in = ssl.MemoryBIO()
        self._out = ssl.MemoryBIO()
        self._obj = ctx.wrap_bio(self._in, self._out, server_side=True)
        self.done = False  #: the handshake is over
        self.closed = False  #: the client sent close_notify
        # plaintext lands here (no 64 KiB bytes object made and shrunk per record)
        self._plain = bytearray(_TLS_CHUNK)

    def feed(self, data: bytes, into: bytearray) -> None:
        """The client's bytes in; the plaintext they complete appended to
        ``into``. Raises :class:`ssl.SSLError` when the handshake or a
        record fails."""
        self._in.write(data)
        if not self.done:
            try:
                self._obj.do_handshake()
            except ssl.SSLWantReadError:
                return
            self.done = True
        obj, plain = self._obj, self._plain
        # read while a record is (or may be) complete: no exception per call
        while self._in.pending or obj.pending():
            try:
                # with a buffer, read returns the count (typeshed says bytes)
                n = cast(int, obj.read(_TLS_CHUNK, plain))
            except ssl.SSLWantReadError:
                return
            except ssl.SSLZeroReturnError:
                self.closed = True
                return
            if not n:
                return
            into += plain if n == _TLS_CHUNK else memoryview(plain)[:n]

    def outgoing(self) -> bytes:
        """What TLS has to send to the client now (handshake, alerts)."""
        return self._out.read() if self._out.pending else b""

    def encrypt(self, data: bytes) -> bytes:
        """``data`` as TLS records for the client."""
        self._obj.write(data)
        return self._out.read()

    def peer_certificate(self) -> bytes | None:
        """The client's certificate (DER), once the handshake is over."""
        return self._obj.getpeercert(binary_form=True)


class _Conn(asyncio.Protocol):
    def __init__(self, server: Server) -> None:
        self.server = server
        self.buf = bytearray()
        self.transport: asyncio.Transport | None = None
        self.pending = 0
        self.taking = False  #: requests are being taken from the buffer
        self.stopping = False  #: dropped as the server stops: nothing more is sent
        self.closed = False
        self.paused_reading = False
        self.paused_writing = False
        self.may_write = True
        self.peer = "?"
        self.tls: _Tls | None = None
        self.handshake_timer: asyncio.TimerHandle | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self.transport = transport
        s = self.server
        s.stats.connections += 1
        peer = transport.get_extra_info("peername")
        self.peer = f"{peer[0]}:{peer[1]}" if isinstance(peer, tuple) else str(peer)
        if s.stats.open >= s.max_clients:
            s.stats.refused_connections += 1
            s.say(f"client {self.peer}: refused, {s.max_clients} clients are connected")
            self.closed = True
            transport.abort()
            return
        s.stats.open += 1
        s.conns.add(self)
        transport.set_write_buffer_limits(high=64 * 1024)
        if s.tls is not None:
            self.tls = _Tls(s.tls)
            self.handshake_timer = asyncio.get_running_loop().call_later(
                HANDSHAKE_TIMEOUT, self._handshake_late)

    def _handshake_late(self) -> None:
        if self.tls is not None and not self.tls.done and not self.closed:
            self._refuse(f"no TLS handshake within {HANDSHAKE_TIMEOUT:g} s")

    def _refuse(self, reason: str) -> None:
        self.server.stats.tls_failures += 1
        self.server.say(f"client {self.peer}: TLS refused: {reason}")
        if self.transport is not None and self.tls is not None:
            alert = self.tls.outgoing()
            if alert:
                self.transport.write(alert)  # the alert that tells the client why
            self.transport.close()

    def _role_may_write(self, der: bytes | None) -> bool:
        if not der:
            return False
        try:
            role = role_of(der)
        except CertificateError as e:
            self.server.say(f"client {self.peer}: its certificate's role cannot be read ({e}); "
                            "reads only")
            return False
        return role is not None and role in self.server.write_roles

    def connected(self) -> bool:
        """Whether this client is still connected: a read it queued is not
        sent upstream once it has gone (nobody would read the reply)."""
        return not self.closed

    def connection_lost(self, exc: Exception | None) -> None:
        if not self.closed:
            self.closed = True
            self.server.stats.open -= 1
        if self.handshake_timer is not None:
            self.handshake_timer.cancel()
        self.server.conns.discard(self)
        if self.buf and not self.stopping:
            self._left()

    def _left(self) -> None:
        """The whole requests still in the buffer of a client that has gone
        (behind its first :data:`PENDING_PER_CLIENT`): its writes are sent all
        the same, as it gave them; its reads are not (nobody would read their
        replies), counted in :attr:`ServeStats.unsent`."""
        s = self.server
        try:
            requests = take_requests(self.buf)
        except BadFrame:  # bytes that are not Modbus TCP: nothing of it is taken
            requests = []
        self.buf.clear()
        for r in requests:
            s.stats.requests += 1
            unit = s.units.upstream(r.unit)
            if r.exception:
                s.stats.malformed += 1
            elif reads_only(r.pdu):
                s.stats.unsent += 1
            elif not self.may_write:
                s.stats.denied += 1
            elif unit is not None:
                self.pending += 1
                s.upstream.submit(unit, r.pdu, s.replier(self, r.tid, r.unit), None)

    def pause_writing(self) -> None:
        # The client does not read its replies: stop taking its requests.
        self.paused_writing = True
        self._pause()

    def resume_writing(self) -> None:
        self.paused_writing = False
        if self.buf:  # requests that waited while it did not read its replies
            self._take()
        self._resume()

    def _pause(self) -> None:
        if not self.paused_reading and self.transport is not None and not self.closed:
            self.paused_reading = True
            self.transport.pause_reading()

    def _resume(self) -> None:
        if (self.paused_reading and not self.paused_writing and self.pending < PENDING_PER_CLIENT
                and self.transport is not None and not self.closed):
            self.paused_reading = False
            self.transport.resume_reading()

    def data_received(self, data: bytes) -> None:
        if self.closed:
            return
        if self.tls is None:
            self.buf += data
        elif not self._tls_in(self.tls, data):
            return
        self._take()

    def _take(self) -> None:
        """Take the requests in the buffer while fewer than
        :data:`PENDING_PER_CLIENT` of this client's wait upstream and it
        reads its replies; the rest stay there (its reading paused) until
        replies have gone back."""
        if self.taking:  # (an upstream that answered at once, from submit)
            return
        self.taking = True
        try:
            while (not self.closed and not self.paused_writing
                   and self.pending < PENDING_PER_CLIENT):
                if not self._submit(PENDING_PER_CLIENT - self.pending):
                    break
        finally:
            self.taking = False
        if self.pending >= PENDING_PER_CLIENT:
            self._pause()

    def _submit(self, most: int) -> bool:
        """Answer or send upstream the first ``most`` requests in the
        buffer; False: there were none (or the bytes were garbage: closed)."""
        s = self.server
        try:
            requests = take_requests(self.buf, most)
        except BadFrame as e:
            s.stats.garbage += 1
            s.say(f"client {self.peer}: bytes that are not Modbus TCP ({e}): closed")
            self.buf.clear()
            self._close()
            return False
        for r in requests:
            s.stats.requests += 1
            function = r.pdu[0]
            if r.exception:
                s.stats.malformed += 1
                self._send(exception_frame(r.tid, r.unit, function, r.exception))
                continue
            if not self.may_write and not reads_only(r.pdu):
                s.stats.denied += 1
                self._send(exception_frame(r.tid, r.unit, function, EX_FUNCTION))
                continue
            unit = s.units.upstream(r.unit)
            if unit is None:
                self._send(exception_frame(r.tid, r.unit, function, EX_PATH))
                continue
            self.pending += 1
            # A read whose client has gone by its turn is not sent (nobody would
            # read the reply); a write is: its client gave it.
            s.upstream.submit(unit, r.pdu, s.replier(self, r.tid, r.unit),
                              self.connected if reads_only(r.pdu) else None)
        return bool(requests)

    def _tls_in(self, tls: _Tls, data: bytes) -> bool:
        """Decrypt ``data`` into the request buffer; False: nothing more to do."""
        was_done = tls.done
        try:
            tls.feed(data, self.buf)
        except ssl.SSLError as e:
            self._refuse(refusal(e))
            return False
        out = tls.outgoing()
        if out and self.transport is not None:
            self.transport.write(out)
        if not was_done and tls.done:
            if self.handshake_timer is not None:
                self.handshake_timer.cancel()
            self.may_write = self._role_may_write(tls.peer_certificate())
        if tls.closed:
            self._close()
            return False
        return bool(self.buf)

    def answered(self, tid: int, unit: int, pdu: bytes) -> None:
        """On the loop: the upstream's reply to one of this client's requests."""
        self.pending -= 1
        if self.closed:
            return
        self._send(mbap_frame(tid, unit, pdu))
        if self.buf:  # requests that waited for their turn in this client's buffer
            self._take()
        self._resume()

    def _send(self, frame: bytes) -> None:
        if self.transport is not None and not self.closed:
            self.server.stats.replies += 1
            self.transport.write(frame if self.tls is None else self.tls.encrypt(frame))

    def _close(self) -> None:
        if self.transport is not None and not self.closed:
            self.transport.abort()

    def abort(self) -> None:
        """Drop the connection (the server is stopping)."""
        self.stopping = True
        self._close()


class Server:
    """A Modbus TCP server on ``host:port`` in front of ``upstream``. With
    ``tls`` (a server :class:`ssl.SSLContext` that requires client
    certificates), only clients whose certificate's role is in
    ``write_roles`` may send the function codes that write."""

    def __init__(self, upstream: Upstream | PipelinedUpstream, host: str, port: int, *,
                 units: UnitMap | None = None, max_clients: int = 64,
                 tls: ssl.SSLContext | None = None, write_roles: frozenset[str] = frozenset(),
                 on_event: Callable[[str], None] | None = None) -> None:
        self.upstream = upstream
        self.host, self.port = host, port
        self.units = units or UnitMap()
        self.max_clients = max_clients
        self.tls = tls
        self.write_roles = write_roles
        self.stats = ServeStats()
        self._on_event = on_event or (lambda _text: None)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server: asyncio.Server | None = None
        self.conns: set[_Conn] = set()

    def say(self, text: str) -> None:
        """One event line."""
        self._on_event(text)

    def replier(self, conn: _Conn, tid: int, unit: int) -> Callable[[bytes], None]:
        """The callback the upstream calls with the reply PDU: on the event
        loop already, or from the upstream's thread."""
        loop = self._loop
        assert loop is not None
        if isinstance(self.upstream, PipelinedUpstream):
            return lambda pdu: conn.answered(tid, unit, pdu)

        def done(pdu: bytes) -> None:
            with contextlib.suppress(RuntimeError):  # the loop closed: the server is stopping
                loop.call_soon_threadsafe(conn.answered, tid, unit, pdu)
        return done

    async def start(self) -> None:
        """Listen (the port is bound when this returns; ``port`` 0 picks one)."""
        self._loop = asyncio.get_running_loop()
        self._server = await self._loop.create_server(
            lambda: _Conn(self), self.host, self.port, reuse_address=True,
            backlog=1024)
        sock = self._server.sockets[0]
        self.port = sock.getsockname()[1]

    async def serve_until(self, stop: asyncio.Event) -> None:
        """Serve until ``stop`` is set, then close every connection."""
        if self._server is None:
            await self.start()
        assert self._server is not None
        await stop.wait()
        self._server.close()
        for conn in list(self.conns):
            conn.abort()
        await asyncio.sleep(0)
