"""``pymb serve --tcp``'s pipelined upstream against a scripted Modbus TCP
device that answers badly on purpose: a reply whose data disagree with its
request, frames of another unit or function under a request's transaction
id, a reply cut in pieces, and bytes that are not Modbus TCP. Each case is
one unit of the script; the client sees what one transaction at a time
would give it."""

from __future__ import annotations

import contextlib
import socket
import struct
import threading
import time
from collections.abc import Iterator
from types import TracebackType
from typing import Self

import pytest
from servekit import RawClient, Served, read_pdu, words

BAD_COUNT = 10  #: answers with a byte count that disagrees with the request
OTHER_UNIT = 11  #: sends a frame of unit 99 under the request's id first, then the reply
OTHER_FUNCTION = 12  #: sends a function 04 reply under the request's id first, then the reply
PIECES = 13  #: sends the reply in three writes, 50 ms apart
GARBAGE = 14  #: sends a header with protocol id 1
EXCEPTION = 15  #: answers exception 02
BAD_ECHO = 16  #: answers a write of one register with another value


def _frame(tid: int, unit: int, pdu: bytes) -> bytes:
    return struct.pack(">HHHB", tid, 0, len(pdu) + 1, unit) + pdu


def _regs(address: int, count: int) -> bytes:
    return struct.pack(f">BB{count}H", 3, 2 * count, *(address + i for i in range(count)))


class Scripted:
    """A Modbus TCP device on 127.0.0.1 that answers each request at once,
    as its unit says (the constants above; any other unit: registers equal
    to their address). Counts its connections."""

    def __init__(self) -> None:
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port = self.listener.getsockname()[1]
        self.connections = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        self.listener.settimeout(0.2)
        while not self._stop.is_set():
            try:
                conn, _ = self.listener.accept()
            except TimeoutError:
                continue
            self.connections += 1
            conn.settimeout(0.2)
            with conn, contextlib.suppress(OSError):
                self._serve(conn)

    def _serve(self, conn: socket.socket) -> None:
        buf = b""
        while not self._stop.is_set():
            try:
                data = conn.recv(4096)
            except TimeoutError:
                continue
            if not data:
                return
            buf += data
            while len(buf) >= 6 and len(buf) >= 6 + struct.unpack(">H", buf[4:6])[0]:
                n = 6 + struct.unpack(">H", buf[4:6])[0]
                tid, _proto, _len, unit = struct.unpack(">HHHB", buf[:7])
                pdu, buf = buf[7:n], buf[n:]
                for piece in self._answer(tid, unit, pdu):
                    conn.sendall(piece)
                    time.sleep(0.05)

    def _answer(self, tid: int, unit: int, pdu: bytes) -> list[bytes]:
        fc = pdu[0]
        if fc == 6:
            value = pdu[3:5] if unit != BAD_ECHO else b"\xff\xff"
            return [_frame(tid, unit, pdu[:3] + value)]
        _fc, address, count = struct.unpack(">BHH", pdu)
        good = _frame(tid, unit, _regs(address, count))
        if unit == BAD_COUNT:
            return [_frame(tid, unit, _regs(address, count)[:-2])]
        if unit == OTHER_UNIT:
            return [_frame(tid, 99, _regs(address, count)) + good]
        if unit == OTHER_FUNCTION:
            return [_frame(tid, unit, b"\x04" + _regs(address, count)[1:]) + good]
        if unit == PIECES:
            return [good[:3], good[3:9], good[9:]]
        if unit == GARBAGE:
            return [struct.pack(">HHHB", tid, 1, 3, unit) + b"\x03\x00"]
        if unit == EXCEPTION:
            return [_frame(tid, unit, b"\x83\x02")]
        return [good]

    def __enter__(self) -> Self:
        return self

    def __exit__(self, et: type[BaseException] | None, ev: BaseException | None,
                 tb: TracebackType | None) -> None:
        self._stop.set()
        self._thread.join(5)
        self.listener.close()


@pytest.fixture
def device() -> Iterator[Scripted]:
    with Scripted() as d:
        yield d


@pytest.fixture
def served(device: Scripted) -> Iterator[Served]:
    # a timeout far longer than any answer here: a 0x0B is the check's, not the clock's
    with Served("--tcp", f"127.0.0.1:{device.port}", "--max-inflight", "4",
                "--timeout", "30") as s:
        yield s


def test_a_reply_that_disagrees_with_its_request_is_answered_0x0b_at_once(
        served: Served) -> None:
    c = RawClient(served.port, timeout=20)
    try:
        t = time.monotonic()
        assert c.ask(1, BAD_COUNT, read_pdu(5, 2)) == bytes((0x83, 0x0B))
        assert c.ask(2, BAD_ECHO, struct.pack(">BHH", 6, 7, 42)) == bytes((0x86, 0x0B))
        assert time.monotonic() - t < 20  # not the 30 s timeout
        assert words(c.ask(3, 1, read_pdu(5, 2))) == [5, 6]  # and the link goes on
    finally:
        c.close()
    assert served.stop() == 0


@pytest.mark.parametrize("unit", [OTHER_UNIT, OTHER_FUNCTION, PIECES])
def test_the_reply_is_found_past_frames_of_another_unit_or_function_and_in_pieces(
        served: Served, unit: int) -> None:
    c = RawClient(served.port, timeout=20)
    try:
        assert words(c.ask(1, unit, read_pdu(100, 3))) == [100, 101, 102]
        assert words(c.ask(2, unit, read_pdu(7, 1))) == [7]
    finally:
        c.close()
    assert served.stop() == 0


def test_an_exception_is_forwarded_and_a_write_echoed(served: Served) -> None:
    c = RawClient(served.port, timeout=20)
    try:
        assert c.ask(1, EXCEPTION, read_pdu(0, 1)) == bytes((0x83, 0x02))
        write = struct.pack(">BHH", 6, 7, 42)
        assert c.ask(2, 1, write) == write
    finally:
        c.close()
    assert served.stop() == 0


def test_bytes_that_are_not_modbus_tcp_end_the_link_and_the_next_request_opens_it(
        device: Scripted, served: Served) -> None:
    c = RawClient(served.port, timeout=20)
    try:
        assert c.ask(1, GARBAGE, read_pdu(0, 1)) == bytes((0x83, 0x0A))
        assert words(c.ask(2, 1, read_pdu(9, 1))) == [9]
    finally:
        c.close()
    assert served.stop() == 0
    assert device.connections == 2
    lost = [line for line in served.stderr_lines if "upstream connection lost" in line]
    assert lost, served.stderr_lines
    # the header as it came (after the upstream's own transaction id)
    assert "the upstream sent bytes that are not Modbus TCP (" in lost[0], lost
    assert lost[0].endswith(" 00 01 00 03 0e 03)"), lost
