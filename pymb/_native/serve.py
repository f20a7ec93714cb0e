"""The requests a Modbus TCP server takes from a client, parsed and checked by
the C core (``csrc/pymb_serve.c``), and its replies framed: the seam of
:mod:`pymb.serve` over ``ffi``/``lib``."""

from __future__ import annotations

from typing import NamedTuple

from pymb._pymb_cffi import ffi, lib

__all__ = ["MAX_FRAME", "BadFrame", "ClientRequest", "exception_frame", "reply_frame",
           "take_requests"]

MAX_FRAME: int = lib.PYMBI_SRV_MAX_FRAME  #: the longest Modbus TCP frame
_MBAP: int = lib.PYMBI_SRV_MBAP


class ClientRequest(NamedTuple):
    """One request a client sent: its transaction id and unit, the PDU
    (function code and data), and the exception code to answer instead of
    forwarding it (0: well formed)."""

    tid: int
    unit: int
    pdu: bytes
    exception: int


class BadFrame(Exception):
    """The client's bytes cannot be Modbus TCP: its connection is closed."""


def take_requests(buf: bytearray) -> list[ClientRequest]:
    """Take every whole request at the start of ``buf`` (removed from it);
    what is left is the start of the next one. Raises :class:`BadFrame` when
    the bytes cannot be a Modbus TCP request (the requests before them are
    lost with the connection)."""
    out: list[ClientRequest] = []
    req = ffi.new("pymbi_srv_req *")
    pos = 0
    n = len(buf)
    data = ffi.from_buffer(buf)
    while pos < n:
        got = lib.pymbi_srv_take(data + pos, n - pos, req)
        if got == 0:
            break
        if got < 0:
            raise BadFrame(bytes(buf[pos:pos + 8]).hex(" "))
        out.append(ClientRequest(req.tid, req.unit, bytes(buf[pos + _MBAP:pos + got]),
                                 req.exception))
        pos += got
    del data
    if pos:
        del buf[:pos]
    return out


def reply_frame(tid: int, unit: int, pdu: bytes) -> bytes:
    """The reply frame to request ``tid`` of ``unit``: MBAP, then ``pdu``."""
    out = ffi.new("uint8_t[]", MAX_FRAME)
    n = lib.pymbi_srv_reply(tid, unit, pdu, len(pdu), out, MAX_FRAME)
    if n < 0:
        raise ValueError(f"a reply PDU holds 1..253 bytes, got {len(pdu)}")
    return bytes(ffi.buffer(out, n))


def exception_frame(tid: int, unit: int, function: int, code: int) -> bytes:
    """The exception reply (``function | 0x80``, ``code``) to request ``tid``."""
    out = ffi.new("uint8_t[]", 9)
    n = lib.pymbi_srv_exception(tid, unit, function & 0xFF, code & 0xFF, out, 9)
    if n < 0:
        raise ValueError(f"exception code must be 1..255, got {code}")
    return bytes(ffi.buffer(out, n))
