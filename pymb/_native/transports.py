"""One factory a transport: a (not yet open) :class:`~pymb._native.link.Link`
whose C line frames as that transport does (csrc/pymb_*.c, one file each)."""

from __future__ import annotations

import ssl

from pymb._native import rtu_silence
from pymb._native.link import Link
from pymb._pymb_cffi import lib
from pymb.wire import bits_per_char

__all__ = ["new_ascii", "new_rtu", "new_tcp", "new_udp"]


def _where(host: str, port: int) -> str:
    """``HOST:PORT`` as the command line takes it: an IPv6 address in brackets."""
    return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"


def new_rtu(port: str, baudrate: int, parity: str, data_bits: int, stop_bits: int) -> Link:
    """A serial-line Link (not yet open)."""
    bits = bits_per_char(parity, stop_bits, data_bits)
    dev = port.encode()
    par = parity.encode()
    return Link(
        port,
        lambda: lib.modbus_new_rtu(dev, baudrate, par, data_bits, stop_bits),
        serial=True,
        silence=rtu_silence(baudrate),
        char_ns=int(lib.pymb_rtu_char_ns(baudrate, bits)),
    )


def new_tcp(host: str, port: int, *, rtu_framing: bool = False,
            silence: float = 0.0,
            tls: tuple[ssl.SSLContext, str | None] | None = None) -> Link:
    """A Modbus TCP Link (not yet open); ``host`` is a name or an address.
    ``rtu_framing``: RTU frames (address, PDU, CRC) on the socket instead of
    MBAP, as transparent serial servers in "raw" mode carry them; a reply of
    unknown length then ends at ``silence`` seconds of silence. ``tls``:
    Modbus/TCP Security, (the client's ssl context, the server name to
    check and send; None: none), the handshake made on every connect."""
    node = host.encode()
    service = str(port).encode()
    return Link(_where(host, port), lambda: lib.modbus_new_tcp_pi(node, service), serial=False,
                host=host, tls=tls,
                framing=lib.PYMB_FRAMING_RTU_OVER_TCP if rtu_framing else lib.PYMB_FRAMING_TCP,
                silence=silence)


def new_ascii(port: str, baudrate: int, parity: str, data_bits: int, stop_bits: int) -> Link:
    """A Modbus ASCII Link on a serial line (not yet open): libmodbus opens
    and sets up the port, pymb frames in characters."""
    dev = port.encode()
    par = parity.encode()
    return Link(port, lambda: lib.modbus_new_rtu(dev, baudrate, par, data_bits, stop_bits),
                serial=True, framing=lib.PYMB_FRAMING_ASCII)


def new_udp(host: str, port: int) -> Link:
    """A Modbus UDP Link (not yet open): MBAP frames in datagrams on a socket
    pymb opens; ``host`` is a name or an address."""
    node = host.encode()
    service = str(port).encode()
    return Link(f"{_where(host, port)}/udp", lambda: lib.modbus_new_tcp_pi(node, service),
                serial=False, host=host, service=str(port), framing=lib.PYMB_FRAMING_UDP)
