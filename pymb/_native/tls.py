"""TLS under a line (Modbus/TCP Security, ``mbaps://``): Python's ssl does the
handshake and the records, over memory buffers, on the line's own socket;
pymb's C request path still builds, sends, receives and checks every frame,
through the line's I/O callbacks (``pymb_line_set_io``). So a TLS line keeps
the transaction-id checks, the quiet window after a failure, the timeouts and
the reconnect policy of a plain one.

What a failure means in words is :func:`tls_words`'s.
"""

from __future__ import annotations

import contextlib
import errno
import os
import select
import ssl
import threading
import time
from typing import Any

from pymb._pymb_cffi import ffi, lib

__all__ = ["ClientContext", "TlsSession", "certificate_refused", "take_raised", "tls_words"]

_CHUNK = 65536  #: raw bytes taken from the socket at a time

# OpenSSL's reasons (ssl.SSLError.reason) that a user can act on, in words.
_REASONS = {
    "WRONG_VERSION_NUMBER": "the server does not speak TLS there (a plain Modbus TCP port?)",
    "RECORD_LAYER_FAILURE": "the server does not speak TLS there (a plain Modbus TCP port?)",
    "UNSUPPORTED_PROTOCOL": "the server offers only TLS versions below 1.2, which are refused",
    "TLSV1_ALERT_PROTOCOL_VERSION": "the server refused TLS 1.2 and later",
    "TLSV13_ALERT_CERTIFICATE_REQUIRED":
        "the server requires a client certificate (give a certificate and its key)",
    "SSLV3_ALERT_HANDSHAKE_FAILURE":
        "the server refused the handshake (does it require a client certificate?)",
    "TLSV1_ALERT_UNKNOWN_CA": "the server refused this client's certificate (unknown CA)",
    "SSLV3_ALERT_BAD_CERTIFICATE": "the server refused this client's certificate",
    "SSLV3_ALERT_CERTIFICATE_EXPIRED":
        "the server refused this client's certificate (it has expired)",
    "SSLV3_ALERT_CERTIFICATE_UNKNOWN": "the server refused this client's certificate",
    "SSLV3_ALERT_UNSUPPORTED_CERTIFICATE":
        "the server refused this client's certificate (not made for a client: its extended "
        "key usage)",
    "SSLV3_ALERT_CERTIFICATE_REVOKED":
        "the server refused this client's certificate (it was revoked)",
    "TLSV1_ALERT_ACCESS_DENIED": "the server refused this client (access denied)",
    "TLSV1_ALERT_DECRYPT_ERROR": "the server refused this client's certificate",
    "UNEXPECTED_EOF_WHILE_READING":
        "the server closed the connection during the TLS handshake (does it refuse this "
        "client, or not speak TLS there?)",
}


# X509_V_ERR_*: a chain that does not lead to the CAs trusted (or is self-signed).
_NOT_SIGNED = frozenset((7, 18, 19, 20, 21))


class ClientContext(ssl.SSLContext):
    """A client's :class:`ssl.SSLContext` that knows which CAs it trusts, so a
    refused certificate can say them."""

    #: the CA file given (None: the system's trusted CAs)
    ca: str | None = None


def certificate_refused(e: ssl.SSLCertVerificationError, *, system_cas: bool,
                        who: str = "server", hint: str = "") -> str:
    """A refused peer certificate in one line: why, and for a chain that does not
    lead to a trusted CA, which CAs it was checked against (``system_cas``: the
    system's, else the one given), then ``hint`` (what to give, for the system's)."""
    why = (e.verify_message or str(e)).rstrip(".")
    if e.verify_code in _NOT_SIGNED:
        why += (f" (not signed by any of the system's trusted CAs{hint})" if system_cas
                else " (not signed by the CA given)")
    return f"the {who}'s certificate was refused: {why}"


def tls_words(e: BaseException, context: ssl.SSLContext | None = None) -> str:
    """A TLS failure in one line: what was refused and why. ``context`` (a
    :class:`ClientContext`) names the CAs a certificate was checked against."""
    if isinstance(e, ssl.SSLCertVerificationError):
        return certificate_refused(
            e, system_cas=isinstance(context, ClientContext) and context.ca is None)
    if isinstance(e, ssl.SSLError):
        reason = e.reason or ""
        if reason in _REASONS:
            return _REASONS[reason]
        return f"TLS failed: {reason.replace('_', ' ').lower() or e}"
    if isinstance(e, TimeoutError):
        return "the TLS handshake did not finish within the timeout"
    if isinstance(e, ConnectionError):
        return (f"the server closed the connection during the TLS handshake "
                f"({os.strerror(e.errno) if e.errno else e})")
    return f"TLS failed: {e}"


class TlsSession:
    """One TLS connection's client side over the descriptor ``fd`` (a
    non-blocking TCP socket the line owns): handshake, then the line's I/O.
    ``error`` keeps the words of the last TLS failure (None: none)."""

    def __init__(self, context: ssl.SSLContext, server_name: str | None, fd: int) -> None:
        self.fd = fd
        self._in = ssl.MemoryBIO()
        self._out = ssl.MemoryBIO()
        self._obj = context.wrap_bio(self._in, self._out, server_side=False,
                                     server_hostname=server_name)
        self.error: str | None = None
        #: plaintext has come from the server since the handshake
        self.received = False
        self.write_timeout = 1.0  #: seconds a write may wait on a full socket
        self._starved = False  # the buffered ciphertext is not a whole record
        self.handle: Any = ffi.new_handle(self)
        self.io: Any = ffi.new("pymb_line_io *")
        self.io.read = lib.pymb_py_tls_read
        self.io.write = lib.pymb_py_tls_write
        self.io.pending = lib.pymb_py_tls_pending
        self.io.arg = self.handle

    # -- the handshake ---------------------------------------------------------

    def handshake(self, timeout: float) -> None:
        """Run the handshake within ``timeout`` seconds; raises ssl.SSLError,
        TimeoutError or OSError (the caller says it in words)."""
        deadline = time.monotonic() + timeout
        while True:
            try:
                self._obj.do_handshake()
            except ssl.SSLWantReadError:
                self._flush(deadline)
                self._fill(deadline)
                continue
            self._flush(deadline)
            return

    def _fill(self, deadline: float) -> None:
        """Wait for ciphertext until ``deadline`` and hand it to ssl."""
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError(errno.ETIMEDOUT, "TLS handshake timed out")
            if not _poll(self.fd, select.POLLIN, left):
                continue
            try:
                data = os.read(self.fd, _CHUNK)
            except BlockingIOError:
                continue
            if not data:
                self._in.write_eof()
            else:
                self._in.write(data)
            return

    def _flush(self, deadline: float) -> None:
        """Write out every pending ciphertext byte by ``deadline``."""
        data = self._out.read()
        view = memoryview(data)
        while view:
            try:
                n = os.write(self.fd, view)
            except BlockingIOError:
                left = deadline - time.monotonic()
                if left <= 0 or not _poll(self.fd, select.POLLOUT, left):
                    raise TimeoutError(errno.ETIMEDOUT, "TLS write timed out") from None
                continue
            view = view[n:]

    # -- the line's I/O (called from C) ----------------------------------------

    def read_into(self, buf: Any, n: int) -> int:
        """Up to ``n`` plaintext bytes into ``buf``: the count, 0 at the end
        of the stream, or a negative errno (-EAGAIN: nothing yet)."""
        target = ffi.buffer(buf, n)
        while True:
            try:
                k = self._obj.read(n, target)
            except ssl.SSLWantReadError:
                if self._out.pending:  # e.g. a key update's answer
                    try:
                        self._flush(time.monotonic() + self.write_timeout)
                    except (OSError, TimeoutError) as e:
                        return -(e.errno or errno.EIO)
                try:
                    data = os.read(self.fd, _CHUNK)
                except BlockingIOError:
                    self._starved = True
                    return -errno.EAGAIN
                except OSError as e:
                    return -(e.errno or errno.EIO)
                self._starved = False
                if data:
                    self._in.write(data)
                else:
                    self._in.write_eof()
                continue
            except (ssl.SSLZeroReturnError, ssl.SSLEOFError):
                return 0  # closed by the peer, as a plain TCP close
            except ssl.SSLError as e:
                self.error = tls_words(e)
                return -errno.EPROTO
            if k:
                self.received = True
                return int(k)
            return 0

    def write(self, buf: Any, n: int) -> int:
        """Encrypt and send all ``n`` bytes: 0 or a negative errno."""
        try:
            self._obj.write(ffi.buffer(buf, n))
            self._flush(time.monotonic() + self.write_timeout)
        except ssl.SSLError as e:
            self.error = tls_words(e)
            return -errno.EPROTO
        except (OSError, TimeoutError) as e:
            return -(e.errno or errno.EIO)
        return 0

    def pending(self) -> int:
        """Plaintext (or whole records) ready without the socket."""
        if self._obj.pending():
            return 1
        return 1 if self._in.pending and not self._starved else 0

    def release(self) -> None:
        """Drop the handle C held (after the line is freed): no cycle stays."""
        self.io = None
        self.handle = None

    def close(self) -> None:
        """Send close_notify if the socket takes it now (never waits)."""
        with contextlib.suppress(ssl.SSLError, ValueError):
            self._obj.unwrap()
        try:
            data = self._out.read()
            if data:
                os.write(self.fd, data)
        except OSError:
            pass


def _poll(fd: int, events: int, seconds: float) -> bool:
    p = select.poll()
    p.register(fd, events)
    return bool(p.poll(max(1, int(seconds * 1000) + 1)))


_raised = threading.local()


def take_raised() -> BaseException | None:
    """The exception a callback of this thread raised (a signal handler's
    KeyboardInterrupt), once; None if none."""
    exc: BaseException | None = getattr(_raised, "exc", None)
    _raised.exc = None
    return exc


def _io_failed(exc_type: Any, exc: BaseException | None, tb: Any) -> int:
    # Kept for the caller to raise (the request fails with EINTR meanwhile).
    _raised.exc = exc if exc is not None else exc_type()
    return -errno.EINTR


@ffi.def_extern(onerror=_io_failed)  # type: ignore[untyped-decorator]
def pymb_py_tls_read(arg: Any, buf: Any, n: int) -> int:
    session: TlsSession = ffi.from_handle(arg)
    return session.read_into(buf, n)


@ffi.def_extern(onerror=_io_failed)  # type: ignore[untyped-decorator]
def pymb_py_tls_write(arg: Any, buf: Any, n: int) -> int:
    session: TlsSession = ffi.from_handle(arg)
    return session.write(buf, n)


@ffi.def_extern(onerror=lambda *_: 0)  # type: ignore[untyped-decorator]
def pymb_py_tls_pending(arg: Any) -> int:
    session: TlsSession = ffi.from_handle(arg)
    return session.pending()
