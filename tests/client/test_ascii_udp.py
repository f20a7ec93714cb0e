"""Modbus ASCII and Modbus UDP against peers that are not pymb's: pymodbus
serving both (ASCII on a pseudo-terminal, UDP on 127.0.0.1), and scripted
responders that frame from the specifications here (the ASCII text and LRC
of [MB-SL] 2.5.2, MBAP datagrams): a bad LRC, late and foreign replies."""

from __future__ import annotations

import time
from collections.abc import Callable

import pytest
from peerkit import PtyPeerBase, Reply, mbap, registers
from wire_peers import UdpPeer, pymodbus_peer, udp_read_reply

import pymb


def lrc(b: bytes) -> int:
    """[MB-SL] 2.5.2.2: the two's complement of the bytes' sum, modulo 256."""
    return -sum(b) & 0xFF


def ascii_frame(b: bytes, *, lrc_delta: int = 0) -> bytes:
    """``b`` (address + PDU) as an ASCII frame; ``lrc_delta`` spoils the LRC."""
    body = b + bytes([(lrc(b) + lrc_delta) & 0xFF])
    return b":" + body.hex().upper().encode() + b"\r\n"


def ascii_bytes(frame: bytes) -> bytes:
    """An ASCII frame's bytes (address, PDU), its LRC checked."""
    assert frame[:1] == b":", frame
    assert frame[-2:] == b"\r\n", frame
    body = bytes.fromhex(frame[1:-2].decode())
    assert lrc(body[:-1]) == body[-1], frame
    return body[:-1]


def exercise(c: pymb.Client) -> None:
    """What any transport must carry to pymodbus's server (unit 17)."""
    assert list(c.read_holding_registers(0, 300)) == [7 * a for a in range(300)]
    assert list(c.read_input_registers(10, 2)) == [40010, 40011]
    assert list(c.read_coils(0, 4)) == [0, 1, 0, 1]
    assert list(c.read_discrete_inputs(0, 4)) == [1, 0, 1, 0]
    c.write_register(900, 4242)
    c.write_registers(901, [1, 2, 3])
    assert list(c.read_holding_registers(900, 4)) == [4242, 1, 2, 3]
    c.write_coils(2, [1, 1])
    assert list(c.read_coils(0, 4)) == [0, 1, 1, 1]
    with pytest.raises(pymb.IllegalDataAddress):
        c.read_holding_registers(990, 20)
    # A refusal leaves the line in step: the next answer is its own.
    assert list(c.read_holding_registers(5, 1)) == [35]
    assert list(c.read_holding_registers(7, 1, slave=1)) == [49]


def test_ascii_against_pymodbus_on_a_pty() -> None:
    with pymodbus_peer("ascii") as path, \
            pymb.AsciiClient(path, 19200, "N", slave=17, timeout=2) as c:
        exercise(c)


def test_udp_against_pymodbus() -> None:
    with pymodbus_peer("udp") as port, \
            pymb.UdpClient("127.0.0.1", int(port), slave=17, timeout=2) as c:
        exercise(c)


def test_async_mirrors_against_pymodbus() -> None:
    import asyncio

    import pymb.aio

    async def main(path: str, port: int) -> tuple[list[int], list[int]]:
        async with pymb.aio.AsyncAsciiClient(path, 19200, slave=1, timeout=2) as a, \
                pymb.aio.AsyncUdpClient("127.0.0.1", port, slave=1, timeout=2) as u:
            return (list(await a.read_holding_registers(3, 2)),
                    list(await u.read_holding_registers(4, 2)))

    with pymodbus_peer("ascii") as path, pymodbus_peer("udp") as port:
        assert asyncio.run(main(path, int(port))) == ([21, 28], [28, 35])


# -- scripted ASCII responder ---------------------------------------------------------------

class AsciiPty(PtyPeerBase):
    """A device on a pseudo-terminal that speaks ASCII: a request ends at CR
    LF; ``script(index, request bytes)`` answers it."""

    def __init__(self, script: Callable[[int, bytes], Reply]) -> None:
        super().__init__()
        self.script = script
        self.requests: list[bytes] = []  #: as received, text

    def received(self, buf: bytes) -> bytes:
        while b"\r\n" in buf:
            frame, buf = buf.split(b"\r\n", 1)
            frame += b"\r\n"
            self.requests.append(frame)
            self.send(self.script(len(self.requests) - 1, ascii_bytes(frame)))
        return buf


def read_reply(req: bytes, values: list[int], *, unit: int | None = None) -> bytes:
    return bytes((req[0] if unit is None else unit, req[1])) + registers(values)


def test_ascii_request_on_the_wire_and_a_bad_lrc() -> None:
    def script(i: int, req: bytes) -> Reply:
        if req[1] == 0x06:
            return [(0, ascii_frame(req))]  # a write's echo
        return [(0, ascii_frame(read_reply(req, [i + 100]), lrc_delta=1 if i == 0 else 0))]

    with AsciiPty(script) as peer, pymb.AsciiClient(peer.port, 19200, slave=1, timeout=1) as c:
        with pytest.raises(pymb.ProtocolError, match="LRC"):
            c.read_holding_registers(0x6B, 3)
        # The frame pymb sent: read 3 holding registers from 0x6B of device 1,
        # its LRC 0x8E (0x100 - (0x01 + 0x03 + 0x6B + 0x03)).
        assert peer.requests[0] == b":0103006B00038E\r\n"
        # After the quiet window a bad frame owes, the next answer is taken.
        assert list(c.read_holding_registers(0x6B, 1)) == [101]
        c.write_register(1, 3)
        assert ascii_bytes(peer.requests[2]) == bytes.fromhex("010600010003")


def test_ascii_reply_digits_in_lower_case_are_read_and_their_lrc_checked() -> None:
    # pymb sends upper case (the specification's); a reply in lower case is
    # read as the same bytes, its LRC checked as any other's.
    def script(i: int, req: bytes) -> Reply:
        frame = ascii_frame(read_reply(req, [0xABCD, 0x00EF]), lrc_delta=1 if i == 1 else 0)
        return [(0, frame.lower())]

    with AsciiPty(script) as peer, pymb.AsciiClient(peer.port, 19200, slave=0x1A,
                                                    timeout=1) as c:
        assert list(c.read_holding_registers(0xBC, 2)) == [0xABCD, 0x00EF]
        with pytest.raises(pymb.ProtocolError, match="LRC"):
            c.read_holding_registers(0xBC, 2)
        assert peer.requests[0] == b":1A0300BC0002" + \
            b"%02X" % lrc(bytes.fromhex("1A0300BC0002")) + b"\r\n"


def test_ascii_late_reply_is_never_a_later_answer() -> None:
    # Request 0 is answered after its timeout; request 1 asks the same
    # address: the late frame (value 111) must not be its answer.
    # It comes 0.25 s after the timeout: within the quiet window the next
    # request to that address first waits for (the timeout again, from the
    # failure), with a margin of 0.25 s either side.
    def script(i: int, req: bytes) -> Reply:
        if i == 0:
            return [(0.75, ascii_frame(read_reply(req, [111])))]
        return [(0, ascii_frame(read_reply(req, [222])))]

    with AsciiPty(script) as peer, \
            pymb.AsciiClient(peer.port, 19200, slave=3, timeout=0.5) as c:
        with pytest.raises(pymb.ModbusTimeout):
            c.read_holding_registers(0, 1)
        assert list(c.read_holding_registers(0, 1)) == [222]
        assert len(peer.requests) == 2


def test_ascii_noise_and_another_address() -> None:
    def script(i: int, req: bytes) -> Reply:
        if i == 0:  # noise, then a frame cut off by a new ':', then the answer
            return [(0, b"\x00zz:0103" + ascii_frame(read_reply(req, [5])))]
        return [(0, ascii_frame(read_reply(req, [6], unit=9)))]

    with AsciiPty(script) as peer, pymb.AsciiClient(peer.port, 19200, slave=4, timeout=1) as c:
        assert list(c.read_holding_registers(0, 1)) == [5]
        with pytest.raises(pymb.ProtocolError, match=r"another address"):
            c.read_holding_registers(0, 1)


#: Frames that fail a read's check, and the words of the ProtocolError each gives.
NOT_THE_ANSWER: dict[str, tuple[Callable[[bytes], bytes], str]] = {
    "another address": (lambda req: ascii_frame(read_reply(req, [9], unit=7)),
                        "another address 7"),
    "the request's echo": (ascii_frame, "byte count"),
    "a bad LRC": (lambda req: ascii_frame(read_reply(req, [9]), lrc_delta=1), "LRC"),
    "a non-digit": (lambda req: ascii_frame(read_reply(req, [9])).replace(b"03", b"0G", 1),
                    "not a hexadecimal digit"),
}


@pytest.mark.parametrize("first", NOT_THE_ANSWER)
def test_ascii_an_answer_after_a_frame_that_is_not_it_is_never_the_next_answer(
        first: str) -> None:
    # [MB-SL] 2.4.1: a frame from another address is no answer, nor is an
    # RS485 adapter's echo of the request; a bad frame may have been anyone's.
    # The device asked may still answer after it, here 20 ms later (value
    # 100): the next request must get its own answer (201), never that one.
    make, words = NOT_THE_ANSWER[first]

    def script(i: int, req: bytes) -> Reply:
        if i == 0:
            return [(0, make(req)), (0.02, ascii_frame(read_reply(req, [100])))]
        return [(0, ascii_frame(read_reply(req, [200 + i])))]

    with AsciiPty(script) as peer, pymb.AsciiClient(peer.port, 19200, slave=4,
                                                    timeout=2.0) as c:
        t0 = time.monotonic()
        with pytest.raises(pymb.ProtocolError, match=words):
            c.read_holding_registers(0, 1)
        assert time.monotonic() - t0 < 1.0  # failed at once, not at the timeout
        assert list(c.read_holding_registers(0, 1)) == [201]


@pytest.mark.parametrize(("reply", "error", "words"), [
    (b":0403020005F\r\n", pymb.ProtocolError, r"odd digit count.*\(received 04 03 02 00 05\)"),
    (b":01030200\n05F5\r\n", pymb.ProtocolError, r"not a hexadecimal digit"),
    (b":01030200\r05F5\r\n", pymb.ProtocolError, r"CR without LF"),
    (b":0403\r\n", pymb.ProtocolError, r"length"),
    (b":" + b"00" * 300 + b"\r\n", pymb.ProtocolError, r"frame longer than"),
    # A frame that never ends: the timeout says what it had.
    (b":0403020005F1\r", pymb.ModbusTimeout, r"incomplete after 6 bytes"),
])
def test_ascii_a_frame_that_is_no_frame_fails_the_request(
        reply: bytes, error: type[pymb.ModbusError], words: str) -> None:
    with AsciiPty(lambda i, req: [(0, reply)]) as peer, \
            pymb.AsciiClient(peer.port, 19200, slave=4, timeout=0.5) as c, \
            pytest.raises(error, match=words):
        c.read_holding_registers(0, 1)


def test_ascii_a_frame_dropped_by_the_inter_character_timeout_is_named_by_the_timeout() -> None:
    # [MB-SL] 2.5.2.1: a gap longer than the inter-character timeout (here
    # byte_timeout, 0.1 s) drops the frame begun; nothing else comes, and the
    # timeout says what that frame had rather than "no reply".
    def script(i: int, req: bytes) -> Reply:
        return [(0, b":040302"), (0.2, b"0005F1\r\n")]

    with AsciiPty(script) as peer, pymb.AsciiClient(peer.port, 19200, slave=4, timeout=0.5,
                                                    byte_timeout=0.1) as c, \
            pytest.raises(pymb.ModbusTimeout, match=r"incomplete after 3 bytes.*04 03 02\)"):
        c.read_holding_registers(0, 1)


# -- scripted UDP responder (wire_peers.UdpPeer) --------------------------------------------

def test_udp_foreign_and_stale_datagrams_are_dropped() -> None:
    # Before each answer: a reply to an older transaction id, one from another
    # unit with the right id, a datagram that is no Modbus frame, and one with
    # protocol id 1. Only the answer is taken.
    def script(i: int, req: bytes) -> Reply:
        tid = int.from_bytes(req[:2], "big")
        return [(0, udp_read_reply(req, [9001], tid=(tid - 1) & 0xFFFF)),
                (0, udp_read_reply(req, [9002], unit=req[6] + 1)),
                (0, b"\x00\x01garbage"),
                (0, mbap(tid, req[6], bytes((3,)) + registers([9003]), proto=1)),
                (0.01, udp_read_reply(req, [i]))]

    with UdpPeer(script) as peer, pymb.UdpClient("127.0.0.1", peer.port, slave=5,
                                                 timeout=1, retries=0) as c:
        for i in range(5):
            assert list(c.read_holding_registers(0, 1)) == [i]
        tids = [int.from_bytes(r[:2], "big") for r in peer.requests]
        assert tids == [tids[0] + k for k in range(5)]


def test_udp_late_reply_is_never_a_later_answer() -> None:
    def script(i: int, req: bytes) -> Reply:
        if i == 0:
            return [(0.5, udp_read_reply(req, [111]))]
        return [(0.3, udp_read_reply(req, [222]))]

    with UdpPeer(script) as peer, pymb.UdpClient("127.0.0.1", peer.port, slave=5,
                                                 timeout=0.25, retries=0) as c:
        with pytest.raises(pymb.ModbusTimeout):
            c.read_holding_registers(0, 1)
        # The late reply (111) arrives while request 1 waits: dropped.
        c.timeout = 2
        assert list(c.read_holding_registers(0, 1)) == [222]


def test_udp_retries_a_lost_request_with_the_same_transaction_id() -> None:
    def script(i: int, req: bytes) -> Reply:
        return [] if i < 2 else [(0, udp_read_reply(req, [7]))]  # the first two are lost

    with UdpPeer(script) as peer:
        with pymb.UdpClient("127.0.0.1", peer.port, slave=1, timeout=0.2, retries=0) as c, \
                pytest.raises(pymb.ModbusTimeout):
            c.read_holding_registers(0, 1)
        with pymb.UdpClient("127.0.0.1", peer.port, slave=1, timeout=0.2, retries=1) as c:
            assert list(c.read_holding_registers(0, 1)) == [7]
        assert peer.requests[1] == peer.requests[2]  # the resend is the same datagram
        assert len(peer.requests) == 3


def test_udp_client_arguments() -> None:
    with pytest.raises(pymb.InvalidArgument, match="retries"):
        pymb.UdpClient("127.0.0.1", 502, retries=11)
    with pytest.raises(pymb.InvalidArgument, match="port"):
        pymb.UdpClient("127.0.0.1", 0)
    assert pymb.UdpClient("127.0.0.1").retries == 2
    c = pymb.UdpClient("127.0.0.1", 1502, retries=3)
    assert (c.host, c.udp_port, c.retries) == ("127.0.0.1", 1502, 3)
    with pytest.raises(pymb.InvalidArgument, match="baudrate"):
        pymb.AsciiClient("/dev/null", 1234)
