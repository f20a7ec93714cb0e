"""Where a client goes: ``HOST:PORT`` as the command line spells it, the
client for it, and whether a host name resolves."""

from __future__ import annotations

import socket

from pymb.client.transports import RtuOverTcpClient, TcpClient
from pymb.errors import InvalidArgument
from pymb.wire import DEFAULT_TIMEOUT

__all__ = ["client_for_address", "parse_host_port", "unresolved"]


def parse_host_port(text: str, *, what: str = "--tcp",
                    port_only: bool = False) -> tuple[str, int]:
    """``HOST:PORT`` as a user typed it -> ``(host, port)``; the one parser of
    pymb's TCP addresses. ``[::1]:502`` loses its brackets, an empty host is
    127.0.0.1, and with ``port_only`` a bare ``PORT`` is accepted too. ``what``
    names the option or key in the one-line error."""
    host, sep, port = str(text).rpartition(":")
    if not sep and port_only:
        host = ""
    if not (sep or port_only) or not port.isdigit():
        raise InvalidArgument(
            f"{what} needs {'[HOST:]PORT' if port_only else 'HOST:PORT'}, got {text!r}")
    number = int(port)
    if number > 65535:
        raise InvalidArgument(f"{what} port must be 0..65535, got {number}")
    return host.strip("[]") or "127.0.0.1", number


def client_for_address(address: str, *, rtu_framing: bool = False, timeout: float = DEFAULT_TIMEOUT,
                       what: str = "--tcp") -> TcpClient | RtuOverTcpClient:
    """A (not yet open) :class:`TcpClient`, or with ``rtu_framing`` an
    :class:`RtuOverTcpClient`, for ``HOST:PORT`` as a user typed it (``what``
    names the option or key in the error)."""
    host, port = parse_host_port(address, what=what)
    cls = RtuOverTcpClient if rtu_framing else TcpClient
    return cls(host, port, timeout=timeout)


def unresolved(host: str) -> str | None:
    """Why ``host`` does not resolve (None when it does)."""
    try:
        socket.getaddrinfo(host, None, type=socket.SOCK_STREAM)
    except socket.gaierror as e:
        return f"the host name {host!r} did not resolve ({e.strerror})"
    except (UnicodeError, OSError) as e:
        return f"the host name {host!r} did not resolve ({e})"
    return None
