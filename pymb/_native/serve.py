"""The requests a Modbus TCP server takes from a client, parsed and checked by
the C core (``csrc/pymb_serve.c``); frames in MBAP (a reply to a client, a
request to a Modbus TCP upstream); an upstream's replies split by the MBAP
length rule and checked against their requests as the request path checks
them: the seam of :mod:`pymb.serve` over ``ffi``/``lib``."""

from __future__ import annotations

from typing import NamedTuple

from pymb._pymb_cffi import ffi, lib

__all__ = ["MAX_FRAME", "REPLY_BAD", "REPLY_EXCEPTION", "REPLY_OK", "REPLY_OTHER", "BadFrame",
           "ClientRequest", "check_reply", "exception_frame", "mbap_frame", "take_frames",
           "take_requests"]

MAX_FRAME: int = lib.PYMBI_SRV_MAX_FRAME  #: the longest Modbus TCP frame
_MBAP: int = lib.PYMBI_SRV_MBAP
_INCOMPLETE: int = lib.PYMB_FRAME_INCOMPLETE
#: what :func:`check_reply` says of a reply frame: the answer to the request
#: (:data:`REPLY_OK`), its exception (:data:`REPLY_EXCEPTION`), a frame of
#: another unit or function (:data:`REPLY_OTHER`: no answer to it), an answer
#: that fails the check (:data:`REPLY_BAD`: a byte count that disagrees, a
#: write's echo that differs)
REPLY_OK, REPLY_EXCEPTION, REPLY_OTHER, REPLY_BAD = range(4)
_STATUS = {lib.PYMB_FRAME_OK: REPLY_OK, lib.PYMB_FRAME_EXCEPTION: REPLY_EXCEPTION,
           lib.PYMB_FRAME_BAD_SLAVE: REPLY_OTHER, lib.PYMB_FRAME_BAD_FUNCTION: REPLY_OTHER}


class ClientRequest(NamedTuple):
    """One request a client sent: its transaction id and unit, the PDU
    (function code and data), and the exception code to answer instead of
    forwarding it (0: well formed)."""

    tid: int
    unit: int
    pdu: bytes
    exception: int


class BadFrame(Exception):
    """The client's bytes cannot be Modbus TCP: its connection is closed.
    :attr:`frames`: the whole frames :func:`take_frames` took before them."""

    def __init__(self, text: str, frames: list[bytes] | None = None) -> None:
        super().__init__(text)
        self.frames: list[bytes] = frames or []


def take_requests(buf: bytearray, most: int | None = None) -> list[ClientRequest]:
    """Take every whole request at the start of ``buf`` (removed from it), or
    the first ``most`` of them; what is left is the start of the next one.
    Raises :class:`BadFrame` when the bytes cannot be a Modbus TCP request
    (the requests before them are lost with the connection)."""
    req = ffi.new("pymbi_srv_req *")
    out: list[ClientRequest] = []
    for frame in take_frames(buf, most):
        lib.pymbi_srv_take(frame, len(frame), req)  # (a whole frame: taken)
        out.append(ClientRequest(req.tid, req.unit, frame[_MBAP:], req.exception))
    return out


def mbap_frame(tid: int, unit: int, pdu: bytes) -> bytes:
    """The frame of ``pdu`` to or from ``unit`` under transaction id ``tid``:
    MBAP, then ``pdu``."""
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


def take_frames(buf: bytearray, most: int | None = None) -> list[bytes]:
    """Take every whole frame at the start of ``buf`` (removed from it), or
    the first ``most`` of them, each as long as its MBAP header says (the C
    core's one rule); what is left is the start of the next one. Raises
    :class:`BadFrame` at a header that cannot be Modbus TCP (the connection
    is lost; the frames before it in its :attr:`~BadFrame.frames`)."""
    out: list[bytes] = []
    pos = 0
    n = len(buf)
    data = ffi.from_buffer(buf)
    while pos < n and (most is None or len(out) < most):
        got = lib.pymbi_mbap_length(data + pos, n - pos)
        if got == _INCOMPLETE or pos + got > n:
            break
        if got < 0:
            raise BadFrame(bytes(buf[pos:pos + 8]).hex(" "), out)
        out.append(bytes(buf[pos:pos + got]))
        pos += got
    del data
    if pos:
        del buf[:pos]
    return out


def check_reply(unit: int, pdu: bytes, frame: bytes) -> int:
    """What reply ``frame`` (a whole frame from :func:`take_frames`) is to
    request ``pdu`` sent to ``unit``: :data:`REPLY_OK`, ... (see there)."""
    status = lib.pymbi_tcp_check(unit, pdu, len(pdu), frame, len(frame), ffi.new("int *"))
    return _STATUS.get(status, REPLY_BAD)
