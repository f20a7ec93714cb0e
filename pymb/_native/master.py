"""The sans-I/O Modbus TCP master of the C core (``csrc/pymb_master.h``,
compiled into the extension): :class:`Master`, one stream's transactions,
and :class:`PollTable`, a poll's read requests made ready for it.

The runners that use it do only I/O and scheduling (``pymb log``'s one TCP
loop, :mod:`pymb.logger.tcploop`, and the bench's bare loop,
:mod:`pymb.bench.fanout`): :meth:`Master.frames` writes a poll's requests,
transaction ids counted on, into one buffer for one ``send``;
:meth:`Master.take` takes whatever bytes came (a part of a reply, several,
in any order), matches each reply to its request by its transaction id,
checks it with the request path's rules and copies its data into the poll's
register image (big-endian; a bit as a 0/1 word). What is not such a reply
comes back as :class:`MasterEvent` records: a refused request (an
exception), a late reply (to a request given up on), a foreign one (to no
request: another transaction id's, kept for the wait's timeout to show), a
bad frame (the stream is out of step).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, NamedTuple

from pymb._pymb_cffi import ffi, lib

__all__ = [
    "BAD",
    "DROPPED",
    "EXCEPTION",
    "FOREIGN",
    "FRAME",
    "LATE",
    "NO_TOKEN",
    "Master",
    "MasterEvent",
    "MasterRead",
    "PollTable",
    "ReadBuffer",
]

FRAME: int = lib.PYMBI_MASTER_FRAME  #: bytes of a read request
HEAD: int = lib.PYMBI_MASTER_HEAD  #: a read reply's bytes before its data
INFLIGHT: int = lib.PYMBI_MASTER_INFLIGHT  #: the most requests in flight on a stream
EXCEPTION: int = lib.PYMBI_EV_EXCEPTION  #: a request refused: :attr:`MasterEvent.code`
LATE: int = lib.PYMBI_EV_LATE  #: the reply to a request given up on (:meth:`Master.forget`)
#: a reply to no request in flight nor given up on (another transaction id's): skipped,
#: and :meth:`Master.dropped` keeps it for the wait's timeout
FOREIGN: int = lib.PYMBI_EV_FOREIGN
BAD: int = lib.PYMBI_EV_BAD  #: a frame that is no answer: the stream is out of step
NO_TOKEN: int = lib.PYMBI_NO_TOKEN  #: an event about no request
#: the words for a :data:`FOREIGN` reply (a client's timeout after one says them too)
DROPPED: str = ffi.string(lib.pymb_frame_strerror(lib.PYMB_FRAME_BAD_TID)).decode()

_frames = lib.pymbi_master_frames
_take = lib.pymbi_master_take
_step = lib.pymbi_master_step
_EVENTS = 32  #: events one take reports at most (it is called again for more)
_NO_IMAGE = ffi.new("uint8_t[]", 1)
_OUT = FRAME * INFLIGHT  #: bytes of the frames buffer


class MasterRead:
    """A read request of a poll and where its data go in the poll's image
    (``offset``, in bytes: 2 a register, 2 a bit or 1 per 8 packed)."""

    __slots__ = ("address", "count", "function", "offset")

    def __init__(self, function: int, address: int, count: int, offset: int) -> None:
        self.function, self.address, self.count, self.offset = function, address, count, offset


class MasterEvent(NamedTuple):
    """What a take saw that is not a reply taken into the image."""

    kind: int  #: :data:`EXCEPTION`, :data:`LATE`, :data:`FOREIGN` or :data:`BAD`
    token: int  #: the request's index in its :class:`PollTable` (:data:`NO_TOKEN`: none)
    code: int  #: :data:`EXCEPTION`: the exception code
    status: int  #: :data:`BAD`: a frame status (``pymb_frame_status``)
    tid: int  #: the frame's transaction id (:data:`BAD`: 0 if its header was bad)


class ReadBuffer:
    """A receive buffer: :attr:`data` to ``recv_into``, and the C view of it."""

    __slots__ = ("c", "data", "view")

    def __init__(self, size: int = 65536) -> None:
        self.data = bytearray(size)
        self.view = memoryview(self.data)
        self.c: Any = ffi.from_buffer("uint8_t[]", self.data)


class PollTable:
    """A poll's read requests (``reads``, in the order the poll sends them;
    each one's index is its token) and the register ``image`` their replies
    fill: a bit as a 0/1 word, or with ``packed_bits`` the reply's bytes of
    bits as they come."""

    __slots__ = ("ends", "image", "image_c", "image_len", "n", "rows", "sizes")

    def __init__(self, reads: Sequence[MasterRead], unit: int, image: bytearray, *,
                 packed_bits: bool = False) -> None:
        n = self.n = len(reads)
        rows = ffi.new("pymbi_mreq[]", max(n, 1))
        for i, r in enumerate(reads):
            row = rows[i]
            row.offset = r.offset
            row.token = i
            row.address = r.address
            row.count = r.count
            row.unit = unit
            row.function = r.function
            packed = packed_bits and r.function <= 2
            row.flags = lib.PYMBI_MREQ_PACKED if packed else 0
            size = (r.count + 7) // 8 if packed else 2 * r.count
            if r.offset + size > len(image):
                raise ValueError(f"request {i}: its reply's data do not fit the image")
        self.rows: Any = rows
        #: each reply's bytes
        self.sizes = [HEAD + ((r.count + 7) // 8 if r.function <= 2 else 2 * r.count)
                      for r in reads]
        #: the bytes of the replies before each request's: ``ends[j] - ends[i]``
        #: is what the replies to requests ``i .. j - 1`` take
        self.ends = [0]
        for size in self.sizes:
            self.ends.append(self.ends[-1] + size)
        self.image = image
        self.image_len = len(image)
        self.image_c: Any = ffi.from_buffer("uint8_t[]", image)


class Master:
    """One stream's master: the requests in flight, a reply cut short, and
    the buffer :meth:`frames` writes to. :meth:`reset` on each new stream."""

    __slots__ = ("_ev", "_framed", "_m", "_out", "_used", "framed", "out", "taken", "view")

    def __init__(self) -> None:
        self._m: Any = ffi.new("pymbi_master *")
        self._ev: Any = ffi.new("pymbi_mevent[]", _EVENTS)
        self._used: Any = ffi.new("size_t *")
        self._framed: Any = ffi.new("size_t *")
        self.out = bytearray(_OUT)  #: the frames :meth:`frames` wrote
        self.view = memoryview(self.out)  #: :attr:`out`, to send a slice of without a copy
        self._out = ffi.from_buffer("uint8_t[]", self.out)
        self.taken = 0  #: replies the last :meth:`take` took into its image
        #: bytes of the next poll's requests the last :meth:`take` framed (0: none)
        self.framed = 0
        lib.pymbi_master_reset(self._m, 1)

    def handles(self) -> tuple[Any, Any, int]:
        """The C master, its events array and that array's length (the C
        loop, :mod:`pymb._native.loop`, takes replies and frames with them)."""
        return self._m, self._ev, _EVENTS

    def reset(self, tid: int = 1) -> None:
        """A new stream: nothing in flight, nothing kept; the first request
        gets id ``tid``."""
        lib.pymbi_master_reset(self._m, tid & 0xFFFF)

    def forget(self) -> None:
        """Nothing is in flight any more: replies on their way are late."""
        lib.pymbi_master_forget(self._m)

    @property
    def next_tid(self) -> int:
        """The transaction id the next request gets; set only while nothing
        is in flight (another master used the stream meanwhile: its ids)."""
        return int(self._m.next_tid)

    @next_tid.setter
    def next_tid(self, tid: int) -> None:
        if self._m.in_flight:
            raise ValueError("the next transaction id is set only with nothing in flight")
        self._m.next_tid = tid & 0xFFFF

    @property
    def in_flight(self) -> int:
        """Requests waiting for their reply."""
        return self._m.in_flight  # type: ignore[no-any-return]

    @property
    def replies(self) -> int:
        """Replies taken into an image since the reset."""
        return self._m.replies  # type: ignore[no-any-return]

    @property
    def kept(self) -> int:
        """Bytes of a reply cut short, kept for the next take."""
        return int(self._m.part_len)

    def partial(self) -> bytes:
        """The bytes of a reply cut short, kept for the next take."""
        m = self._m
        return bytes(ffi.buffer(m.part, m.part_len))

    def dropped(self) -> bytes:
        """The last :data:`FOREIGN` reply of this wait (b"": none): the
        device answered, under another transaction id. A wait begins when
        requests are framed with none in flight, at :meth:`forget` and at
        :meth:`reset`."""
        m = self._m
        return bytes(ffi.buffer(m.drop, m.drop_len)) if m.dropped else b""

    def bad_frame(self) -> bytes:
        """The frame (or its first bytes) a :data:`BAD` event was about."""
        m = self._m
        return bytes(ffi.buffer(m.bad, m.bad_len))

    def pending(self) -> list[int]:
        """The tokens of the requests in flight, oldest first."""
        n = int(self._m.in_flight)
        tokens = ffi.new("uint32_t[]", max(n, 1))
        got = lib.pymbi_master_pending(self._m, tokens, n)
        return [int(tokens[i]) for i in range(min(got, n))]

    def frames(self, table: PollTable, first: int, n: int) -> int:
        """Write requests ``first .. first + n - 1`` of ``table`` to
        :attr:`out` with the next transaction ids, now in flight; returns the
        bytes written."""
        if first < 0 or n < 0 or first + n > table.n:
            raise ValueError(f"requests {first}+{n} are not in a poll of {table.n}")
        got: int = _frames(self._m, table.rows + first if first else table.rows, n,
                           table.image_len, self._out, _OUT)
        if got < 0:
            raise ValueError(f"requests {first}+{n}: more than {INFLIGHT} in flight")
        return got

    def take(self, buf: ReadBuffer, start: int, length: int, table: PollTable | None,
             again: PollTable | None = None) -> tuple[int, int]:
        """Take ``buf.data[start:start + length]`` into ``table``'s image
        (``None``: no poll under way, nothing in flight): (events, bytes
        used); the events are :meth:`event` ``0 .. events - 1``. Fewer bytes
        used than given: the events filled up (take the rest after them) or
        a :data:`BAD` event ended the take.

        With ``again`` (reads of ``table``'s image): a take that ends the
        poll (no event, every byte used, nothing in flight or kept) writes
        all of ``again``'s requests to :attr:`out` at once, as :meth:`frames`
        would, the next poll in flight from then on; :attr:`framed` says
        their bytes (0: not framed)."""
        if table is None:
            image, size = _NO_IMAGE, 0
        else:
            image, size = table.image_c, table.image_len
        m = self._m
        before = m.replies
        data = buf.c + start if start else buf.c
        if again is None:
            got: int = _take(m, data, length, image, size, self._ev, _EVENTS, self._used)
            self.framed = 0
        else:
            if table is None or again.image is not table.image:
                raise ValueError("the next poll's requests are not reads of this poll's image")
            got = _step(m, data, length, image, size, self._ev, _EVENTS, self._used,
                        again.rows, again.n, self._out, _OUT, self._framed)
            self.framed = self._framed[0]
        if got < 0:
            raise ValueError("a request in flight does not fit this poll's image")
        self.taken = m.replies - before
        return got, self._used[0]

    def event(self, i: int) -> MasterEvent:
        """Event ``i`` of the last :meth:`take`."""
        e = self._ev[i]
        return MasterEvent(int(e.kind), int(e.token), int(e.code), int(e.status), int(e.tid))
