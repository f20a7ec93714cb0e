"""A poll's read requests made ready for the C core's pipelined Modbus TCP
calls (``pymbi_mbap_frames`` and ``pymbi_mbap_take``, compiled into the
extension from ``csrc/pymb_mbap.c``): :class:`PollTable`.

The one TCP loop (:mod:`pymb.logger.tcploop`) sends a poll's requests with
one C call that writes their frames, transaction ids counted on, into one
buffer (one ``send``), and takes the replies that came, in the order they
were sent, with one C call per read: each reply's first 9 bytes checked and
its data bytes copied into the poll's sample image. Whatever else comes (an
exception, a late or early reply, another order, garbage) is left to the
loop's own checks. The only module of :mod:`pymb.logger` that touches
cffi's ``ffi`` and ``lib``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol

from pymb._pymb_cffi import ffi, lib

__all__ = ["FRAME", "PollTable", "ReadBuffer"]

FRAME: int = lib.PYMBI_MBAP_FRAME  #: bytes of a read request
_frames = lib.pymbi_mbap_frames
_take = lib.pymbi_mbap_take


class _Request(Protocol):
    """What a table row is made of (:class:`pymb.logger.tcpunits.Spec`)."""

    tail: bytes  #: the request after its transaction id
    head: bytes  #: its reply's first 9 bytes after the transaction id
    size: int  #: the reply's bytes
    offset: int  #: where its data bytes go in the image


class ReadBuffer:
    """The loop's one receive buffer: :attr:`data` to ``recv_into`` (after
    up to ``spare`` bytes kept from the last read), and the C view of it."""

    __slots__ = ("c", "data", "view")

    def __init__(self, size: int = 65536, spare: int = 1024) -> None:
        self.data = bytearray(size + spare)
        self.view = memoryview(self.data)
        self.c: Any = ffi.from_buffer("uint8_t[]", self.data)


class PollTable:
    """The requests of one poll (``reqs``, in the order the poll sends them)
    for the C calls, with the sample ``image`` their replies fill and a
    buffer for their frames."""

    __slots__ = ("_image", "_image_len", "_out", "_reqs", "_used", "ends", "n", "out", "sizes")

    def __init__(self, reqs: Sequence[_Request], image: bytearray) -> None:
        n = self.n = len(reqs)
        table = ffi.new("pymbi_mbap_req[]", max(n, 1))
        for i, r in enumerate(reqs):
            row = table[i]
            row.tail = list(r.tail)
            row.head = list(r.head)
            row.size = r.size
            row.offset = r.offset
            if r.size < 9 or r.offset + r.size - 9 > len(image):
                raise ValueError(f"request {i}: its reply's data do not fit the image")
        self._reqs = table
        self.sizes = [r.size for r in reqs]  #: each reply's bytes
        #: the bytes of the replies before each request's: ``ends[j] - ends[i]``
        #: is what the replies to requests ``i .. j - 1`` take
        self.ends = [0]
        for size in self.sizes:
            self.ends.append(self.ends[-1] + size)
        self._image = ffi.from_buffer("uint8_t[]", image)
        self._image_len = len(image)
        self.out = bytearray(FRAME * max(n, 1))  #: the frames :meth:`frames` wrote
        self._out = ffi.from_buffer("uint8_t[]", self.out)
        self._used = ffi.new("size_t *")

    def frames(self, first: int, n: int, tid: int) -> int:
        """Write requests ``first .. first + n - 1`` to :attr:`out` with
        transaction ids ``tid``, ``tid + 1``, ... (modulo 65536); returns
        the bytes written."""
        got: int = _frames(self._reqs, self.n, first, n, tid, self._out, len(self.out))
        if got < 0:
            raise ValueError(f"requests {first}+{n} are not in a poll of {self.n}")
        return got

    def take(self, first: int, n: int, tid: int, buf: ReadBuffer, length: int) -> tuple[int, int]:
        """Take the replies in ``buf.data[:length]`` to requests ``first ..
        first + n - 1`` (sent with ids from ``tid``), in that order, into the
        image: (replies taken, bytes they took). It stops before the first
        that is not the next one whole."""
        got: int = _take(self._reqs, self.n, first, n, tid, buf.c, length, self._image,
                         self._image_len, self._used)
        if got < 0:
            raise ValueError(f"requests {first}+{n} are not in a poll of {self.n}")
        return got, int(self._used[0])
