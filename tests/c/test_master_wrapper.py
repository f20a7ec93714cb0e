"""The C core's sans-I/O Modbus TCP master seen from Python
(:mod:`pymb._native.master`), the way the TCP loop and the bench drive it:
replies taken in pieces and out of order, and the events a take reports
(exception, late, foreign, bad) against frames written here from the Modbus
TCP specification ([MB-TCP] 3.1.3, [MB-APP] 6.3, 7)."""

from __future__ import annotations

import pytest

from pymb._native.master import (
    BAD,
    EXCEPTION,
    FOREIGN,
    LATE,
    NO_TOKEN,
    Master,
    MasterRead,
    PollTable,
    ReadBuffer,
)


def _reply(tid: int, unit: int, pdu: bytes) -> bytes:
    return tid.to_bytes(2, "big") + b"\x00\x00" + (len(pdu) + 1).to_bytes(2, "big") + \
        bytes((unit,)) + pdu


def _regs(tid: int, fill: int, count: int) -> bytes:
    return _reply(tid, 7, bytes((3, 2 * count)) + bytes(range(fill, fill + 2 * count)))


def _take_all(m: Master, rx: ReadBuffer, data: bytes, t: PollTable) -> list[tuple[int, int]]:
    rx.data[:len(data)] = data
    n, used = m.take(rx, 0, len(data), t)
    assert used == len(data)
    return [(e.kind, e.token) for e in (m.event(i) for i in range(n))]


def test_a_poll_in_pieces_and_out_of_order() -> None:
    image = bytearray(12)
    t = PollTable([MasterRead(3, 0, 2, 8), MasterRead(3, 10, 4, 0)], 7, image)
    m = Master()
    m.reset(0x10)
    size = m.frames(t, 0, 2)
    assert bytes(m.out[:size]) == bytes.fromhex(
        "0010 0000 0006 07 03 0000 0002" "0011 0000 0006 07 03 000a 0004".replace(" ", ""))
    assert m.in_flight == 2
    assert m.pending() == [0, 1]
    data = _regs(0x11, 0x40, 4) + _regs(0x10, 0x80, 2)  # the second request's reply first
    rx = ReadBuffer()
    for k in range(len(data)):  # one byte at a time
        assert _take_all(m, rx, data[k:k + 1], t) == []
        if k < 16:  # (the first reply is 17 bytes)
            assert m.in_flight == 2
    assert m.in_flight == 0
    assert m.replies == 2
    assert m.kept == 0
    assert bytes(image) == bytes(range(0x40, 0x48)) + bytes(range(0x80, 0x84))


def test_exception_late_foreign_and_bad() -> None:
    image = bytearray(4)
    t = PollTable([MasterRead(3, 0, 1, 0), MasterRead(3, 1, 1, 2)], 7, image)
    m = Master()
    m.reset(1)
    m.frames(t, 0, 2)
    rx = ReadBuffer()
    got = _take_all(m, rx, _reply(2, 7, b"\x83\x02") + _regs(9, 0, 1), t)
    assert got == [(EXCEPTION, 1), (FOREIGN, NO_TOKEN)]
    assert m.event(0).code == 2
    assert m.pending() == [0]
    m.forget()  # (a timeout): its reply is late now
    assert _take_all(m, rx, _regs(1, 0, 1), t) == [(LATE, NO_TOKEN)]
    m.frames(t, 0, 1)  # id 3; a reply from another unit is no answer to it
    assert _take_all(m, rx, _reply(3, 8, b"\x03\x02\x00\x01"), t) == [(BAD, 0)]
    assert m.bad_frame() == _reply(3, 8, b"\x03\x02\x00\x01")
    m.reset()
    m.frames(t, 0, 1)
    rx.data[:9] = bytes.fromhex("0001 0001 0005 07 03 02".replace(" ", ""))  # protocol 1
    n, used = m.take(rx, 0, 9, t)
    assert n == 1
    assert used == 9
    assert m.event(0).kind == BAD
    assert m.bad_frame() == bytes(rx.data[:9])


def test_a_part_of_a_reply_is_kept_and_refusals() -> None:
    image = bytearray(4)
    t = PollTable([MasterRead(4, 0, 2, 0)], 1, image)
    m = Master()
    m.frames(t, 0, 1)
    rx = ReadBuffer()
    whole = _reply(1, 1, bytes((4, 4, 1, 2, 3, 4)))
    assert _take_all(m, rx, whole[:5], t) == []
    assert m.partial() == whole[:5]
    assert _take_all(m, rx, whole[5:], t) == []
    assert bytes(image) == b"\x01\x02\x03\x04"
    with pytest.raises(ValueError, match="do not fit"):
        PollTable([MasterRead(4, 0, 3, 0)], 1, image)
    with pytest.raises(ValueError, match="not in a poll"):
        m.frames(t, 1, 1)
    bits = bytearray(2)
    packed = PollTable([MasterRead(1, 0, 10, 0)], 1, bits, packed_bits=True)
    m.frames(packed, 0, 1)
    assert _take_all(m, rx, _reply(2, 1, b"\x01\x02\xcd\x01"), packed) == []
    assert bytes(bits) == b"\xcd\x01"


def test_a_take_that_ends_the_poll_frames_the_next_one() -> None:
    image = bytearray(12)
    t = PollTable([MasterRead(3, 0, 2, 8), MasterRead(3, 10, 4, 0)], 7, image)
    m = Master()
    m.reset(0x20)
    m.frames(t, 0, 2)
    rx = ReadBuffer()
    first, second = _regs(0x20, 0x80, 2), _regs(0x21, 0x40, 4)
    rx.data[:len(first)] = first
    assert m.take(rx, 0, len(first), t, t) == (0, len(first))
    assert (m.framed, m.in_flight) == (0, 1)  # a reply still missing: nothing framed
    rx.data[:len(second)] = second
    assert m.take(rx, 0, len(second), t, t) == (0, len(second))
    assert image == bytes(range(0x40, 0x48)) + bytes(range(0x80, 0x84))
    assert (m.framed, m.in_flight, m.pending()) == (24, 2, [0, 1])
    assert bytes(m.out[:24]) == bytes.fromhex(
        "0022 0000 0006 07 03 0000 0002" "0023 0000 0006 07 03 000a 0004".replace(" ", ""))
    # an exception ends the poll: an event, the next one not framed
    data = _reply(0x22, 7, bytes((0x83, 0x02))) + _regs(0x23, 0x10, 4)
    rx.data[:len(data)] = data
    n, used = m.take(rx, 0, len(data), t, t)
    assert (n, used, m.framed, m.in_flight) == (1, len(data), 0, 0)
    assert (m.event(0).kind, m.event(0).token, m.event(0).code) == (EXCEPTION, 0, 2)
    # a plain take says nothing framed; the next poll's reads go to the same image
    assert m.take(rx, 0, 0, t) == (0, 0)
    assert m.framed == 0
    other = PollTable([MasterRead(3, 0, 2, 0)], 7, bytearray(4))
    with pytest.raises(ValueError, match="image"):
        m.take(rx, 0, 0, t, other)
