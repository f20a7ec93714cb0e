"""Where a client goes: ``HOST:PORT`` (or ``mbaps://HOST[:PORT]``, Modbus/TCP
Security) as the command line spells it, the client for it, and whether a
host name resolves."""

from __future__ import annotations

import socket

from pymb.client.tls import MBAPS_PORT, TlsConfig
from pymb.client.transports import RtuOverTcpClient, TcpClient
from pymb.errors import InvalidArgument
from pymb.wire import DEFAULT_TIMEOUT

__all__ = ["MBAPS", "client_for_address", "is_mbaps", "parse_address", "parse_host_port",
           "unresolved"]

MBAPS = "mbaps://"  #: the scheme of a Modbus/TCP Security address


def parse_host_port(text: str, *, what: str = "--tcp",
                    port_only: bool = False) -> tuple[str, int]:
    """``HOST:PORT`` as a user typed it -> ``(host, port)``; the one parser of
    pymb's TCP addresses. ``[::1]:502`` loses its brackets, an empty host is
    127.0.0.1, and with ``port_only`` a bare ``PORT`` is accepted too. ``what``
    names the option or key in the one-line error."""
    if "://" in str(text):  # a URL: only --tcp takes one (mbaps://), by parse_address
        raise InvalidArgument(f"{what} needs {'[HOST:]PORT' if port_only else 'HOST:PORT'}, "
                              f"got {text!r}")
    host, sep, port = str(text).rpartition(":")
    if not sep and port_only:
        host = ""
    if not (sep or port_only) or not port.isdigit():
        raise InvalidArgument(
            f"{what} needs {'[HOST:]PORT' if port_only else 'HOST:PORT'}, got {text!r}")
    if ":" in host and not (host.startswith("[") and host.endswith("]")):
        raise InvalidArgument(f"{what}: an IPv6 address goes in brackets, [ADDRESS]:PORT "
                              f"(e.g. [::1]:502), got {text!r}")
    number = int(port)
    if number > 65535:
        raise InvalidArgument(f"{what} port must be 0..65535, got {number}")
    return host.strip("[]") or "127.0.0.1", number


def is_mbaps(address: str) -> bool:
    """Whether ``address`` names Modbus/TCP Security (``mbaps://...``)."""
    return str(address).lower().startswith(MBAPS)


def parse_address(text: str, *, what: str = "--tcp") -> tuple[str, int, bool]:
    """``HOST:PORT`` or ``mbaps://HOST[:PORT]`` as a user typed it ->
    ``(host, port, tls)``; ``mbaps://`` without a port is port 802."""
    text = str(text)
    if not is_mbaps(text):
        return (*parse_host_port(text, what=what), False)
    rest = text[len(MBAPS):].rstrip("/")
    if not rest or rest.startswith(":"):
        raise InvalidArgument(f"{what} needs mbaps://HOST[:PORT], got {text!r}")
    if rest.endswith("]") or ":" not in rest or (rest.count(":") > 1 and "]" not in rest):
        rest = f"{rest}:{MBAPS_PORT}"  # no port: Modbus/TCP Security's own
    host, port = parse_host_port(rest, what=what)
    return host, port, True


def client_for_address(address: str, *, rtu_framing: bool = False, timeout: float = DEFAULT_TIMEOUT,
                       what: str = "--tcp",
                       tls: TlsConfig | None = None) -> TcpClient | RtuOverTcpClient:
    """A (not yet open) :class:`TcpClient`, or with ``rtu_framing`` an
    :class:`RtuOverTcpClient`, for ``HOST:PORT`` as a user typed it (``what``
    names the option or key in the error). ``mbaps://HOST[:PORT]`` is a
    TcpClient with Modbus/TCP Security: ``tls`` (None: the system's trusted
    CAs, no client certificate); ``tls`` with a plain address is refused."""
    host, port, secure = parse_address(address, what=what)
    if secure:
        if rtu_framing:
            raise InvalidArgument(f"{what} takes HOST:PORT: RTU over TCP has no TLS "
                                  f"(mbaps:// is Modbus TCP's), got {address!r}")
        return TcpClient(host, port, timeout=timeout, tls=tls or TlsConfig())
    if tls is not None:
        raise InvalidArgument(f"TLS settings need an mbaps://HOST[:PORT] address, "
                              f"not {what} {address}")
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
