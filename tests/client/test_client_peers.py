"""The client's framing against peers that are not pymb's: scripted
responders written from the Modbus specifications (tests/wire_peers.py),
Debian's libmodbus and pymodbus as servers. The MBAP header, RTU silence
and CRC, late and trickled replies, the frame limits."""

from __future__ import annotations

import struct
import threading
import time
from array import array
from pathlib import Path

import pytest
from peerkit import mbap, registers, rtu
from wire_peers import (
    RawPty,
    RawTcp,
    answer_read,
    build_libmodbus_server,
    libmodbus_server,
    tcp_request,
)

import pymb
from pymb import _native


def test_tcp_transaction_ids_increment_per_client() -> None:
    with RawTcp(lambda i, adu: [(0, answer_read(adu, [i]))]) as peer, \
            pymb.TcpClient("127.0.0.1", peer.port, slave=1, timeout=2) as c:
        for i in range(5):
            assert list(c.read_holding_registers(0, 1)) == [i]
        tids = [tcp_request(a)[0] for a in peer.requests]
        assert tids == [tids[0] + k for k in range(5)]
        assert all(struct.unpack(">H", a[2:4])[0] == 0 for a in peer.requests)


def test_tcp_late_reply_never_becomes_a_later_answer() -> None:
    # Request 0 is answered (value 111) long after its timeout; every later
    # request at once with its own index. Back-to-back polling must get each
    # request's own value, never 111 and never one behind.
    def script(i: int, adu: bytes) -> list[tuple[float, bytes]]:
        if i == 0:
            return [(0.6, answer_read(adu, [111]))]
        return [(0, answer_read(adu, [i]))]

    with RawTcp(script) as peer, pymb.TcpClient("127.0.0.1", peer.port, slave=1,
                                                timeout=0.25) as c:
        t0 = time.monotonic()
        with pytest.raises(pymb.ModbusTimeout):
            c.read_holding_registers(0, 1)
        assert time.monotonic() - t0 < 0.25 + 0.2
        c.timeout = 2
        got = [c.read_holding_registers(0, 1)[0] for _ in range(4)]
        assert got == [1, 2, 3, 4]


@pytest.mark.parametrize("lie", ["foreign_tid", "protocol_1", "length_long", "length_short",
                                 "other_unit"])
def test_tcp_reply_must_match_tid_protocol_length_and_unit(lie: str) -> None:
    def script(i: int, adu: bytes) -> list[tuple[float, bytes]]:
        tid, unit, _pdu = tcp_request(adu)
        body = bytes((3,)) + registers([7])
        if i > 0:  # afterwards an honest peer: the line must still work
            return [(0, mbap(tid, unit, body))]
        if lie == "foreign_tid":
            return [(0, mbap(tid ^ 0x5A5A, unit, body))]
        if lie == "protocol_1":
            return [(0, mbap(tid, unit, body, proto=1))]
        if lie == "length_long":
            return [(0, mbap(tid, unit, body + b"\x00", length=len(body) + 2))]
        if lie == "length_short":
            return [(0, mbap(tid, unit, body, length=len(body)))]
        return [(0, mbap(tid, 9, body))]

    with RawTcp(script) as peer, pymb.TcpClient("127.0.0.1", peer.port, slave=1,
                                                timeout=0.3) as c:
        expected = pymb.ModbusTimeout if lie == "foreign_tid" else pymb.ProtocolError
        with pytest.raises(expected) as ei:
            c.read_holding_registers(0, 1)
        if lie == "other_unit":
            assert "another address 9" in str(ei.value)
        c.timeout = 2
        assert list(c.read_holding_registers(0, 1)) == [7]


def test_tcp_any_function_code_uses_the_mbap_length() -> None:
    ident = bytes(range(40))

    def script(i: int, adu: bytes) -> list[tuple[float, bytes]]:
        tid, unit, pdu = tcp_request(adu)
        return [(0, mbap(tid, unit, bytes((pdu[0],)) + ident))]

    with RawTcp(script) as peer, pymb.TcpClient("127.0.0.1", peer.port, slave=1) as c:
        assert c.raw_request(0x2B, b"\x0e\x01\x00") == ident
        assert c.raw_request(0x41, b"\x01\x02") == ident


@pytest.mark.parametrize("code", [0x0C, 0x11, 0x80, 0xFF])
def test_exception_codes_above_0x0b_are_device_exceptions(code: int) -> None:
    def tcp_script(i: int, adu: bytes) -> list[tuple[float, bytes]]:
        tid, unit, pdu = tcp_request(adu)
        return [(0, mbap(tid, unit, bytes((pdu[0] | 0x80, code))))]

    with RawTcp(tcp_script) as peer, pymb.TcpClient("127.0.0.1", peer.port, slave=1) as tc:
        with pytest.raises(pymb.DeviceException) as ei:
            tc.read_holding_registers(0, 1)
        assert ei.value.code == code
        assert not isinstance(ei.value, pymb.ProtocolError)

    def rtu_script(i: int, frame: bytes) -> list[tuple[float, bytes]]:
        return [(0, rtu(bytes((frame[0], frame[1] | 0x80, code))))]

    with RawPty(rtu_script) as pty, pymb.RtuClient(pty.port, 115200, slave=1) as c:
        with pytest.raises(pymb.DeviceException) as ei:
            c.raw_request(0x41, b"")
        assert ei.value.code == code


def test_rtu_unknown_function_reply_ends_by_silence_crc_over_all() -> None:
    data = bytes(range(30))

    def script(i: int, frame: bytes) -> list[tuple[float, bytes]]:
        fc = frame[1]
        if fc == 0x08:  # diagnostics, return query data: the request echoed
            return [(0, frame)]
        if i == 2:  # a corrupted last byte: the CRC over the whole frame fails
            f = rtu(bytes((frame[0], fc)) + data)
            return [(0, f[:-3] + bytes((f[-3] ^ 1,)) + f[-2:])]
        return [(0, rtu(bytes((frame[0], fc)) + data))]

    with RawPty(script) as pty, pymb.RtuClient(pty.port, 115200, slave=1) as c:
        assert c.raw_request(0x08, b"\x00\x00\x12\x34") == b"\x00\x00\x12\x34"
        assert c.raw_request(0x41) == data
        with pytest.raises(pymb.ProtocolError):
            c.raw_request(0x41)
        assert c.raw_request(0x41, response_length=30) == data
        with pytest.raises(pymb.ProtocolError):  # shorter than the reply: CRC fails
            c.raw_request(0x41, response_length=10)


def test_failed_call_returns_within_its_timeout_and_late_reply_is_dropped() -> None:
    def script(i: int, frame: bytes) -> list[tuple[float, bytes]]:
        value = 111 if i == 0 else 222
        reply = rtu(bytes((frame[0], 3)) + registers([value]))
        return [(0.45 if i == 0 else 0, reply)]

    with RawPty(script) as pty, pymb.RtuClient(pty.port, 115200, slave=1,
                                               timeout=0.3) as c:
        t0 = time.monotonic()
        with pytest.raises(pymb.ModbusTimeout) as ei:
            c.read_holding_registers(0, 1)
        elapsed = time.monotonic() - t0
        assert elapsed < 0.3 + 0.12, elapsed  # not twice the timeout
        assert "no reply within the 0.3 s timeout" in str(ei.value)
        # The late 111 arrives while the next request settles: never returned.
        assert list(c.read_holding_registers(0, 1)) == [222]


def test_scan_of_silent_addresses_costs_one_timeout_each() -> None:
    def script(i: int, frame: bytes) -> list[tuple[float, bytes]]:
        if frame[0] == 9:
            return [(0, rtu(bytes((9, 3)) + registers([9])))]
        return []

    with RawPty(script) as pty, pymb.RtuClient(pty.port, 115200, timeout=0.2) as c:
        t0 = time.monotonic()
        for slave in range(1, 6):
            with pytest.raises(pymb.ModbusTimeout):
                c.read_holding_registers(0, 1, slave=slave)
        elapsed = time.monotonic() - t0
        assert elapsed < 5 * 0.2 + 0.4, elapsed  # not 5 x 2 x 0.2
        assert list(c.read_holding_registers(0, 1, slave=9)) == [9]


def test_late_reply_from_a_scanned_address_is_not_the_next_answer() -> None:
    # Slave 1 answers 0.3 s late; slave 2 at once. The late frame from 1
    # arrives during the request to 2: it is dropped, 2's own reply is taken.
    def script(i: int, frame: bytes) -> list[tuple[float, bytes]]:
        if frame[0] == 1:
            return [(0.3, rtu(bytes((1, 3)) + registers([1])))]
        return [(0.1, rtu(bytes((2, 3)) + registers([2])))]

    with RawPty(script) as pty, pymb.RtuClient(pty.port, 115200, timeout=0.25) as c:
        with pytest.raises(pymb.ModbusTimeout):
            c.read_holding_registers(0, 1, slave=1)
        c.timeout = 1.0
        assert list(c.read_holding_registers(0, 1, slave=2)) == [2]


def test_rtu_over_tcp_client_against_a_raw_gateway() -> None:
    def script(i: int, frame: bytes) -> list[tuple[float, bytes]]:
        if i == 1:  # a bad CRC once
            f = rtu(bytes((frame[0], 3)) + registers([5]))
            return [(0, f[:-1] + bytes((f[-1] ^ 0xFF,)))]
        if frame[1] == 0x41:
            return [(0, rtu(bytes((frame[0], 0x41)) + b"abc"))]
        return [(0, rtu(bytes((frame[0], 3)) + registers([5])))]

    with RawTcp(script, rtu_frames=True) as peer, \
            pymb.RtuOverTcpClient("127.0.0.1", peer.port, slave=7, timeout=1) as c:
        assert list(c.read_holding_registers(0, 1)) == [5]
        with pytest.raises(pymb.ProtocolError, match="CRC"):
            c.read_holding_registers(0, 1)
        assert list(c.read_holding_registers(0, 1)) == [5]
        assert c.raw_request(0x41) == b"abc"
        assert peer.requests[0] == rtu(bytes((7, 3, 0, 0, 0, 1)))


@pytest.fixture(scope="module")
def libmodbus_exe(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return build_libmodbus_server(tmp_path_factory.mktemp("libmodbus"))


@pytest.mark.parametrize("mode", ["tcp", "rtu", "rtu-over-tcp"])
def test_against_a_libmodbus_server(libmodbus_exe: Path, mode: str) -> None:
    with libmodbus_server(libmodbus_exe, mode) as where:
        c: pymb.Client
        if mode == "tcp":
            c = pymb.TcpClient("127.0.0.1", int(where), slave=17, timeout=2)
        elif mode == "rtu":
            c = pymb.RtuClient(where, 115200, slave=17, timeout=2)
        else:
            c = pymb.RtuOverTcpClient("127.0.0.1", int(where), slave=17, timeout=2)
        with c:
            assert list(c.read_holding_registers(0, 5)) == [0, 3, 6, 9, 12]
            assert list(c.read_input_registers(10, 2)) == [40010, 40011]
            regs = c.read_holding_registers(0, 300)  # split into 125-register requests
            assert list(regs) == [3 * i for i in range(300)]
            c.write_register(5, 4242)
            c.write_registers(6, [1, 2, 3])
            assert list(c.read_holding_registers(5, 4)) == [4242, 1, 2, 3]
            c.write_coil(1, True)
            c.write_coils(2, [1, 0, 1])
            assert list(c.read_coils(0, 5)) == [1, 1, 1, 0, 1]
            with pytest.raises(pymb.IllegalFunction):  # libmodbus: unknown code -> 01
                # (no data: libmodbus's RTU server frames requests by function code)
                c.raw_request(0x41, b"" if mode != "tcp" else b"\x01")
            with pytest.raises(pymb.IllegalDataAddress):
                c.read_holding_registers(990, 20)
            assert list(c.read_holding_registers(0, 1)) == [0]


def test_crc16_counts_the_bytes_of_any_buffer() -> None:
    a = array("H", [0x3132, 0x3334, 0x3536])
    raw = a.tobytes()
    assert pymb.crc16(memoryview(a)) == pymb.crc16(raw)
    assert pymb.crc16(a) == pymb.crc16(raw)
    assert _native.with_crc(a)[:-2] == raw
    b = bytearray(b"0123456789")
    assert pymb.crc16(memoryview(b)[::2]) == pymb.crc16(bytes(b[::2]))


def test_rtu_silence_has_the_spec_floor() -> None:
    assert _native.rtu_silence(9600) == pytest.approx(38.5 / 9600, abs=2e-6)
    assert _native.rtu_silence(19200) == pytest.approx(38.5 / 19200, abs=2e-6)
    for baud in (38400, 115200, 921600):
        assert _native.rtu_silence(baud) == pytest.approx(0.00175)


BAUDS = (9600, 19200, 38400, 57600, 115200)


def poll_line(baud: int, repeat_after: float | None, reject: bool,
              n: int) -> tuple[int, int, int]:
    """n reads of one register through an emulated line: (right, stale, failed)."""
    from wire_peers import EmulatedLine

    right = stale = failed = 0
    with EmulatedLine(baud, repeat_after) as line, \
            pymb.RtuClient(line.port, baud, slave=1, timeout=0.5, reject_early=reject) as c:
        for asked in range(n):
            try:
                v = c.read_holding_registers(asked, 1)[0]
            except pymb.ModbusError:
                failed += 1
                continue
            if v == asked:
                right += 1
            else:
                stale += 1
    return right, stale, failed


@pytest.mark.parametrize("baud", [9600, 115200])
def test_rejecting_early_bytes_never_loses_a_genuine_reply(baud: int) -> None:
    right, stale, failed = poll_line(baud, None, True, 20)
    assert (right, stale, failed) == (20, 0, 0)


@pytest.mark.timing
@pytest.mark.parametrize(("baud", "gap"), [(b, 0.0) for b in BAUDS] + [
    (9600, 3.5 * 11 / 9600)])
def test_rejecting_early_bytes_closes_the_prompt_duplicate(baud: int, gap: float) -> None:
    # A repeater that sends each reply again `gap` after the original: the
    # copy is taken as the next answer without the check, never with it
    # (errors are allowed: a copy that runs into the next reply is garbage).
    # The README's table is this measurement (poll_line); above 19200 a
    # repeater gap of t3.5 (1.75 ms) outlasts a short request's wire time plus
    # 3.5 characters, and the copy passes: the limit stated there. At 19200
    # the margin is thin enough for a loaded machine's scheduling to eat.
    _, stale_with, _ = poll_line(baud, gap, True, 40)
    _, stale_without, _ = poll_line(baud, gap, False, 40)
    assert stale_with == 0
    if gap:
        assert stale_without > 0


@pytest.mark.parametrize("transport", ["rtu", "rtu-over-tcp", "tcp"])
def test_diagnostics_echo_of_every_length_up_to_the_frame_limit(transport: str) -> None:
    # fc 0x08 (return query data) echoes its request: with 252 data bytes the
    # RTU frame is 256 bytes, the limit itself, ended by the line's silence.
    def echo(i: int, frame: bytes) -> list[tuple[float, bytes]]:
        return [(0, frame)]

    peer_cm = RawPty(echo) if transport == "rtu" else RawTcp(
        echo, rtu_frames=transport == "rtu-over-tcp")
    with peer_cm as peer:
        c: pymb.Client
        if transport == "rtu":
            c = pymb.RtuClient(str(peer.port), 115200, slave=1, timeout=2)
        elif transport == "tcp":
            c = pymb.TcpClient("127.0.0.1", int(peer.port), slave=1, timeout=2)
        else:
            c = pymb.RtuOverTcpClient("127.0.0.1", int(peer.port), slave=1, timeout=2)
        with c:
            for n in (0, 1, 2, 4, 100, 250, 251, 252):
                data = bytes((7 * k + n) & 0xFF for k in range(n))
                assert c.raw_request(0x08, data) == data, n


def test_rtu_frame_of_unknown_length_past_the_limit_is_refused() -> None:
    def long_reply(i: int, frame: bytes) -> list[tuple[float, bytes]]:
        return [(0, rtu(bytes((frame[0], 0x41)) + bytes(260)))]

    with RawPty(long_reply) as pty, pymb.RtuClient(pty.port, 115200, slave=1, timeout=1) as c, \
            pytest.raises(pymb.ProtocolError, match="longer than 256"):
        c.raw_request(0x41)


def test_byte_timeout_below_the_silence_does_not_fail_a_frame_ended_by_silence() -> None:
    # At 9600 baud t3.5 is 4 ms: a byte timeout of 2 ms must not turn the
    # silence that ends a reply of unknown length into a timeout.
    def script(i: int, frame: bytes) -> list[tuple[float, bytes]]:
        return [(0, rtu(bytes((frame[0], 0x41)) + b"abc"))]

    with RawPty(script) as pty, pymb.RtuClient(pty.port, 9600, slave=1, timeout=1,
                                               byte_timeout=0.002) as c:
        assert c.raw_request(0x41) == b"abc"


def test_a_reply_trickled_byte_by_byte_cannot_hold_a_call_past_its_timeout() -> None:
    # A reply of unknown length ends by silence; a peer that keeps sending a
    # byte every 10 ms (under RTU over TCP's 20 ms frame silence) for 2.5 s
    # must not keep a call with timeout=0.3 waiting until the frame limit.
    def trickle(i: int, frame: bytes) -> list[tuple[float, bytes]]:
        return [(0.01, bytes((1, 0x41) if k == 0 else (k,))) for k in range(250)]

    with RawTcp(trickle, rtu_frames=True) as peer, \
            pymb.RtuOverTcpClient("127.0.0.1", peer.port, slave=1, timeout=0.3) as c:
        t0 = time.monotonic()
        with pytest.raises(pymb.ModbusError):
            c.raw_request(0x41)
        assert time.monotonic() - t0 < 0.3 + 0.02 + 0.3


def _device_objects(reply: bytes) -> dict[int, bytes]:
    """The objects of a Read Device Identification reply ([MB-AP] 6.21):
    MEI type, read code, conformity, more follows, next id, count, then
    (id, length, value) each."""
    assert reply[0] == 0x0E
    objects, i = {}, 6
    for _ in range(reply[5]):
        oid, n = reply[i], reply[i + 1]
        objects[oid] = reply[i + 2:i + 2 + n]
        i += 2 + n
    assert i == len(reply)
    return objects


@pytest.mark.parametrize("mode", ["tcp", "rtu-over-tcp"])
def test_against_a_pymodbus_server(mode: str) -> None:
    pytest.importorskip("pymodbus")
    from pymodbus_server import IDENTITY
    from wire_peers import pymodbus_server

    with pymodbus_server(mode) as port:
        cls = pymb.TcpClient if mode == "tcp" else pymb.RtuOverTcpClient
        with cls("127.0.0.1", port, slave=17, timeout=2) as c:
            assert list(c.read_holding_registers(0, 300)) == [7 * a for a in range(300)]
            assert list(c.read_input_registers(10, 2)) == [40010, 40011]
            assert list(c.read_coils(0, 4)) == [0, 1, 0, 1]
            assert list(c.read_discrete_inputs(0, 4)) == [1, 0, 1, 0]
            c.write_register(900, 4242)
            c.write_registers(901, [1, 2, 3])
            c.mask_write_register(902, 0x00FF, 0x1200)
            assert list(c.read_holding_registers(900, 4)) == [4242, 1, 0x1202, 3]
            c.write_coils(2, [1, 1])
            assert list(c.read_coils(0, 4)) == [0, 1, 1, 1]
            assert list(c.write_read_registers(950, [9, 8], 949, 3)) == [7 * 949, 9, 8]
            # Device identification, several objects per reply (regular: six).
            basic = _device_objects(c.raw_request(0x2B, b"\x0e\x01\x00"))
            assert basic == {0: IDENTITY["VendorName"].encode(),
                             1: IDENTITY["ProductCode"].encode(),
                             2: IDENTITY["MajorMinorRevision"].encode()}
            regular = _device_objects(c.raw_request(0x2B, b"\x0e\x02\x00"))
            assert regular[5] == IDENTITY["ModelName"].encode()
            assert len(regular) == 6
            assert c.raw_request(0x08, b"\x00\x00\x12\x34") == b"\x00\x00\x12\x34"
            assert c.report_slave_id().startswith(IDENTITY["VendorName"].encode())
            with pytest.raises(pymb.IllegalDataAddress):
                c.read_holding_registers(990, 20)
            # Threads sharing the client each get their own values.
            wrong: list[object] = []

            def worker(k: int) -> None:
                for j in range(25):
                    a = (97 * k + 13 * j) % 800
                    try:
                        got = list(c.read_holding_registers(a, 3))
                    except pymb.ModbusError as e:  # pragma: no cover - reported below
                        wrong.append(e)
                        continue
                    if got != [7 * x for x in range(a, a + 3)]:
                        wrong.append((a, got))

            threads = [threading.Thread(target=worker, args=(k,)) for k in range(4)]
            for t in threads:
                t.start()
            for t in threads:
                t.join()
            assert wrong == []
        if mode == "tcp":
            # pymodbus answers an unknown function with exception code in
            # function 0x80, which is no answer to 0x41: a ProtocolError,
            # and the stream is in step, so the next call is not delayed.
            with pymb.TcpClient("127.0.0.1", port, slave=1, timeout=2) as c:
                with pytest.raises(pymb.ProtocolError, match="another function"):
                    c.raw_request(0x41)
                t0 = time.monotonic()
                assert list(c.read_holding_registers(1, 1)) == [7]
                assert time.monotonic() - t0 < 1.0


def test_tcp_a_whole_bad_frame_costs_the_next_request_nothing() -> None:
    # Replies from another unit or to another function are whole frames: the
    # stream is in step, and the next request is answered at once (no quiet
    # window of the 2 s timeout).
    def script(i: int, adu: bytes) -> list[tuple[float, bytes]]:
        tid, unit, _pdu = tcp_request(adu)
        if i == 0:
            return [(0, mbap(tid, unit ^ 1, bytes((3,)) + registers([1])))]
        if i == 1:
            return [(0, mbap(tid, unit, bytes((0x84, 2))))]
        return [(0, mbap(tid, unit, bytes((3,)) + registers([i])))]

    with RawTcp(script) as peer, pymb.TcpClient("127.0.0.1", peer.port, slave=1,
                                                timeout=2) as c:
        t0 = time.monotonic()
        for _ in range(2):
            with pytest.raises(pymb.ProtocolError):
                c.read_holding_registers(0, 1)
        assert list(c.read_holding_registers(0, 1)) == [2]
        assert time.monotonic() - t0 < 1.0
