"""Wire-level correctness (issue 10) against peers that are not pymb's:
scripted responders written from the Modbus specifications
(tests/wire_peers.py) and Debian's libmodbus as a server."""

from __future__ import annotations

import gc
import math
import os
import signal
import struct
import threading
import time
import warnings
from array import array
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from conftest import wait_until
from peerkit import mbap, registers, rtu
from wire_peers import RawPty, RawTcp, build_libmodbus_server, libmodbus_server

import pymb
from pymb import _native


def _tcp_req(adu: bytes) -> tuple[int, int, bytes]:
    tid, _, _, unit = struct.unpack(">HHHB", adu[:7])
    return tid, unit, adu[7:]


def _answer_read(adu: bytes, values: list[int]) -> bytes:
    tid, unit, pdu = _tcp_req(adu)
    return mbap(tid, unit, bytes((pdu[0],)) + registers(values))


# -- Modbus TCP: pymb owns the MBAP header --------------------------------------------


def test_tcp_transaction_ids_increment_per_client() -> None:
    with RawTcp(lambda i, adu: [(0, _answer_read(adu, [i]))]) as peer, \
            pymb.TcpClient("127.0.0.1", peer.port, slave=1, timeout=2) as c:
        for i in range(5):
            assert list(c.read_holding_registers(0, 1)) == [i]
        tids = [_tcp_req(a)[0] for a in peer.requests]
        assert tids == [tids[0] + k for k in range(5)]
        assert all(struct.unpack(">H", a[2:4])[0] == 0 for a in peer.requests)


def test_tcp_late_reply_never_becomes_a_later_answer() -> None:
    # Request 0 is answered (value 111) long after its timeout; every later
    # request at once with its own index. Back-to-back polling must get each
    # request's own value, never 111 and never one behind.
    def script(i: int, adu: bytes) -> list[tuple[float, bytes]]:
        if i == 0:
            return [(0.6, _answer_read(adu, [111]))]
        return [(0, _answer_read(adu, [i]))]

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
        tid, unit, _pdu = _tcp_req(adu)
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
        tid, unit, pdu = _tcp_req(adu)
        return [(0, mbap(tid, unit, bytes((pdu[0],)) + ident))]

    with RawTcp(script) as peer, pymb.TcpClient("127.0.0.1", peer.port, slave=1) as c:
        assert c.raw_request(0x2B, b"\x0e\x01\x00") == ident
        assert c.raw_request(0x41, b"\x01\x02") == ident


@pytest.mark.parametrize("code", [0x0C, 0x11, 0x80, 0xFF])
def test_exception_codes_above_0x0b_are_device_exceptions(code: int) -> None:
    def tcp_script(i: int, adu: bytes) -> list[tuple[float, bytes]]:
        tid, unit, pdu = _tcp_req(adu)
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


# -- RTU: any function code, any length -------------------------------------------------


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


# -- a failed call returns within its timeout -------------------------------------------


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


# -- signals ------------------------------------------------------------------------------


class _Interrupt(Exception):
    pass


def _client(transport: str, port: object, **kw: Any) -> pymb.Client:
    """A client for `transport` ("rtu", "tcp", "rtu-over-tcp") to a test peer."""
    if transport == "rtu":
        return pymb.RtuClient(str(port), 115200, slave=1, **kw)
    if transport == "tcp":
        return pymb.TcpClient("127.0.0.1", int(str(port)), slave=1, **kw)
    return pymb.RtuOverTcpClient("127.0.0.1", int(str(port)), slave=1, **kw)


@pytest.mark.parametrize("transport", ["rtu", "tcp", "rtu-over-tcp"])
def test_signal_handler_that_raises_interrupts_a_blocked_call(transport: str) -> None:
    def silent(i: int, frame: bytes) -> list[tuple[float, bytes]]:
        return []

    def handler(signum: int, frame: object) -> None:
        raise _Interrupt

    old = signal.signal(signal.SIGALRM, handler)
    try:
        peer_cm = RawPty(silent) if transport == "rtu" else RawTcp(
            silent, rtu_frames=transport == "rtu-over-tcp")
        with peer_cm as peer:
            c = _client(transport, peer.port, timeout=5)
            with c:
                signal.setitimer(signal.ITIMER_REAL, 0.2)
                t0 = time.monotonic()
                with pytest.raises(_Interrupt):
                    c.read_holding_registers(0, 1)
                late = time.monotonic() - t0 - 0.2
                assert late < 0.5, late  # seen at once, not after the 5 s timeout
                # Again while the next request pays the quiet window the
                # interrupt left owed: that wait is interruptible too.
                signal.setitimer(signal.ITIMER_REAL, 0.2)
                t0 = time.monotonic()
                with pytest.raises(_Interrupt):
                    c.read_holding_registers(0, 1)
                assert time.monotonic() - t0 - 0.2 < 0.5
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


@pytest.mark.timing
def test_signal_interrupts_within_100_ms() -> None:
    def handler(signum: int, frame: object) -> None:
        raise _Interrupt

    old = signal.signal(signal.SIGALRM, handler)
    try:
        with RawPty(lambda i, f: []) as pty, \
                pymb.RtuClient(pty.port, 115200, slave=1, timeout=5) as c:
            signal.setitimer(signal.ITIMER_REAL, 0.2)
            t0 = time.monotonic()
            with pytest.raises(_Interrupt):
                c.read_holding_registers(0, 1)
            assert time.monotonic() - t0 - 0.2 < 0.1
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


@pytest.mark.parametrize("transport", ["rtu", "tcp", "rtu-over-tcp"])
def test_signal_handler_that_returns_does_not_fail_a_good_read(transport: str) -> None:
    # The reply comes in two fragments 150 ms apart, with byte_timeout 0.5 s;
    # SIGUSR1 arrives between them (and more during the wait), its handler
    # returns normally: the read succeeds.
    seen: list[int] = []

    def script(i: int, frame: bytes) -> list[tuple[float, bytes]]:
        body = bytes((3,)) + registers([4242, 4343])
        reply = (mbap(_tcp_req(frame)[0], 1, body) if transport == "tcp"
                 else rtu(bytes((1,)) + body))
        return [(0, reply[:4]), (0.15, reply[4:])]

    def handler(signum: int, frame: object) -> None:
        seen.append(signum)

    old = signal.signal(signal.SIGUSR1, handler)
    pid = os.getpid()
    try:
        peer_cm = RawPty(script) if transport == "rtu" else RawTcp(
            script, rtu_frames=transport == "rtu-over-tcp")
        with peer_cm as peer, _client(transport, peer.port, timeout=2, byte_timeout=0.5) as c:
            stop = threading.Event()

            def pester() -> None:
                while not stop.wait(0.02):
                    os.kill(pid, signal.SIGUSR1)

            t = threading.Thread(target=pester)
            t.start()
            try:
                for _ in range(3):
                    assert list(c.read_holding_registers(0, 2)) == [4242, 4343]
            finally:
                stop.set()
                t.join()
        assert seen
    finally:
        signal.signal(signal.SIGUSR1, old)


# -- values and arguments -----------------------------------------------------------------


@pytest.fixture
def echo_pty() -> Iterator[tuple[pymb.RtuClient, list[bytes]]]:
    def script(i: int, frame: bytes) -> list[tuple[float, bytes]]:
        if frame[1] in (5, 6):
            return [(0, frame)]
        if frame[1] in (15, 16):
            return [(0, rtu(frame[:6]))]
        if frame[1] == 3:
            n = frame[5]
            return [(0, rtu(bytes((frame[0], 3)) + registers(list(range(n)))))]
        return []

    with RawPty(script) as pty, pymb.RtuClient(pty.port, 115200, slave=1, timeout=1) as c:
        yield c, pty.requests


@pytest.mark.parametrize("value", ["False", b"\x00", 2, -1, 0.5, math.nan, None, [1]])
def test_write_coil_accepts_only_bools_and_0_1(
        echo_pty: tuple[pymb.RtuClient, list[bytes]], value: object) -> None:
    c, requests = echo_pty
    with pytest.raises((TypeError, pymb.InvalidArgument)):
        c.write_coil(0, value)  # type: ignore[arg-type]
    with pytest.raises((TypeError, pymb.InvalidArgument)):
        c.write_coils(0, [True, value])  # type: ignore[list-item]
    assert requests == []


def test_coil_and_register_values_that_mean_one_thing(
        echo_pty: tuple[pymb.RtuClient, list[bytes]]) -> None:
    c, requests = echo_pty
    c.write_coil(0, True)
    c.write_coil(1, 0)
    c.write_coils(0, [1, 0, True, False])
    c.write_registers(0, [1, 65535])
    c.write_registers(0, array("H", [7]))
    assert requests[0][:6] == bytes((1, 5, 0, 0, 0xFF, 0))
    assert requests[1][:6] == bytes((1, 5, 0, 1, 0, 0))
    assert requests[2][:8] == bytes((1, 15, 0, 0, 0, 4, 1, 0b0101))
    n = len(requests)
    for bad in ([2, -1, "0"], "1010", b"\x01\x00"):
        with pytest.raises((TypeError, pymb.InvalidArgument)):
            c.write_coils(0, bad)  # type: ignore[arg-type]
    for bad_regs in (b"\x01\x02", bytearray(b"\x01\x02"), [True], [1.0], [65536], [-1],
                     ["1"]):
        with pytest.raises((TypeError, pymb.InvalidArgument)):
            c.write_registers(0, bad_regs)  # type: ignore[arg-type]
    with pytest.raises((TypeError, pymb.InvalidArgument)):
        c.write_register(0, True)
    assert len(requests) == n


def test_bad_arguments_never_escape_as_low_level_errors(
        echo_pty: tuple[pymb.RtuClient, list[bytes]]) -> None:
    c, requests = echo_pty
    a = array("H", bytes(20))
    strided = memoryview(a)[::2]
    cases: list[Callable[[], object]] = [
        lambda: c.read_holding_registers_into(0, strided),
        lambda: c.read_holding_registers_into(0, b"\x00\x00"),
        lambda: c.read_holding_registers_into(0, array("B", bytes(4))),
        lambda: c.raw_request(0x41, [256]),  # type: ignore[arg-type]
        lambda: c.raw_request(0x41, "text"),  # type: ignore[arg-type]
        lambda: c.raw_request(0x41, bytes(253)),
        lambda: c.raw_request(0x41, response_length=-1),
        lambda: c.drain(-1),
        lambda: c.drain(math.nan),
        lambda: c.drain(math.inf),
        lambda: c.set_timeout(math.nan),
        lambda: c.set_timeout(math.inf),
        lambda: c.read_holding_registers(math.nan, 1),  # type: ignore[arg-type]
        lambda: c.write_register(0, 2**70),
    ]
    for case in cases:
        try:
            case()
        except (TypeError, pymb.InvalidArgument):
            pass
        else:
            pytest.fail("accepted a bad argument")
    assert requests == []
    # A contiguous 2-D-free buffer of the right kind works, and fills it all.
    c.read_holding_registers_into(0, a)
    assert list(a) == list(range(10))


def test_rts_delay_out_of_range_and_failed_connect_leave_nothing_open() -> None:
    with RawPty(lambda i, f: []) as pty:
        with pytest.raises(pymb.InvalidArgument):
            pymb.RtuClient(pty.port, rts_delay=3600)
        c = pymb.RtuClient(pty.port, serial_mode="rs485")  # a pty has no RS485 mode
        with pytest.raises(pymb.ModbusConnectionError):
            c.connect()
        assert not c.connected
        assert c.fileno() == -1
        with pytest.raises(pymb.ModbusConnectionError, match="not connected"):
            c.read_holding_registers(0, 1, slave=1)
        with pymb.RtuClient(pty.port, slave=1) as again:  # the port's lock was released
            assert again.connected


# -- lifetimes ----------------------------------------------------------------------------


def test_dropped_client_warns_and_releases_descriptor_and_lock() -> None:
    with RawPty(lambda i, f: []) as pty:
        c = pymb.RtuClient(pty.port, slave=1)
        c.connect()
        fd = c.fileno()
        with warnings.catch_warnings(record=True) as w:
            warnings.simplefilter("always")
            del c
            gc.collect()
        assert any(issubclass(x.category, ResourceWarning) for x in w)
        try:
            still = os.readlink(f"/proc/self/fd/{fd}") == pty.port
        except OSError:
            still = False
        assert not still
        with pymb.RtuClient(pty.port, slave=1) as again:
            assert again.connected


# -- RTU over TCP -------------------------------------------------------------------------


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


# -- against libmodbus as the server ------------------------------------------------------


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


# -- smaller points -----------------------------------------------------------------------


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


# -- RTU over TCP in the commands, the TOML bus config and the simulators -------------------


def test_simulator_serves_rtu_over_tcp_to_pymodbus() -> None:
    pm_client = pytest.importorskip("pymodbus.client")
    framer = pytest.importorskip("pymodbus").FramerType.RTU
    from pymb.sim import Simulator

    with Simulator(["coolpro", "hub:250"], transport="rtu-over-tcp", seed=3) as sim:
        # held still, the image read after the request is the one served (the
        # hub refreshes its values whenever the line is quiet for 0.25 s)
        sim.clock.freeze()
        c = pm_client.ModbusTcpClient(sim.host, port=sim.tcp_port, framer=framer, timeout=2,
                                      retries=0)
        assert c.connect()
        try:
            rr = c.read_input_registers(0, count=8, device_id=40)
            assert not rr.isError()
            assert len(rr.registers) == 8
            rr = c.read_holding_registers(31, count=100, device_id=250)
            assert not rr.isError()
            assert list(rr.registers) == list(
                sim.device(250).registers(31, 100))  # type: ignore[attr-defined]
        finally:
            c.close()
        with pymb.RtuOverTcpClient(sim.host, sim.tcp_port, slave=250) as mine:
            assert len(mine.read_holding_registers(31, 700)) == 700
        sim.faults.inject("bad_crc")
        with pymb.RtuOverTcpClient(sim.host, sim.tcp_port, slave=40) as mine, \
                pytest.raises(pymb.ProtocolError, match="CRC"):
            mine.read_input_registers(0, 8)


def test_rtu_over_tcp_flag_in_commands_and_toml(tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    import json

    from pymb.cli import main
    from pymb.logger import load_config
    from pymb.sim import Simulator

    with Simulator(["coolpro", "hub:250"], transport="rtu-over-tcp", seed=2) as sim:
        where = f"{sim.host}:{sim.tcp_port}"
        assert main(["read", "hub", "--rtu-over-tcp", where, "--address", "250",
                     "--json"]) == 0
        doc = json.loads(capsys.readouterr().out)
        assert len(doc["values"]["temperature_c"]) == 100
        assert main(["scan", "--rtu-over-tcp", where, "--range", "39-41", "--json"]) == 0
        assert "40" in capsys.readouterr().out
        out = tmp_path / "x.jsonl"
        assert main(["log", "--rtu-over-tcp", where, "--device", "coolpro", "--format", "jsonl",
                     "--out", str(out), "--seconds", "0.5", "--quiet"]) == 0
        assert out.read_text().count("\n") > 0
        toml = tmp_path / "bus.toml"
        toml.write_text(f'[[bus]]\nname = "gw"\nrtu_over_tcp = "{where}"\n'
                        '[[bus.device]]\ntype = "coolpro"\naddress = 40\n')
        cfg = load_config(toml)
        client = cfg.buses[0].client()
        assert isinstance(client, pymb.RtuOverTcpClient)
        with client:
            assert len(client.read_input_registers(0, 8, slave=40)) == 8
    assert main(["read", "coolpro", "--rtu-over-tcp", "nowhere"]) == 2
    assert "HOST:PORT" in capsys.readouterr().err


# -- duplicated replies: rejecting bytes before the request can have been answered ----------

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


@pytest.mark.ctrl_c
def test_ctrl_c_interrupts_a_blocked_read_in_a_real_process() -> None:
    # A real SIGINT (Python's default handler: KeyboardInterrupt) to a process
    # blocked in a read with a 30 s timeout: it ends at once with the
    # KeyboardInterrupt, not after the timeout.
    import subprocess
    import sys

    with RawTcp(lambda i, adu: []) as peer:
        code = (
            "import sys, pymb\n"
            f"c = pymb.TcpClient('127.0.0.1', {peer.port}, slave=1, timeout=30)\n"
            "c.connect()\n"
            "print('ready', flush=True)\n"
            "try:\n"
            "    c.read_holding_registers(0, 1)\n"
            "except KeyboardInterrupt:\n"
            "    print('interrupted', flush=True)\n"
            "    sys.exit(3)\n"
        )
        proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE,
                                text=True, cwd=str(Path(__file__).resolve().parent.parent))
        try:
            assert proc.stdout is not None
            assert proc.stdout.readline().strip() == "ready"
            # until the request is on the wire: the read is blocked
            wait_until(lambda: peer.requests, "the request on the wire", 10, every=0.01)
            t0 = time.monotonic()
            proc.send_signal(signal.SIGINT)
            rc = proc.wait(10)
            assert time.monotonic() - t0 < 5
            assert rc == 3
            assert proc.stdout.read().strip() == "interrupted"
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait(10)


# -- found by review: frame limits, byte timeout, argument kinds ----------------------------


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


def test_raw_request_data_must_be_bytes_that_mean_one_thing(
        echo_pty: tuple[pymb.RtuClient, list[bytes]]) -> None:
    c, requests = echo_pty
    # bytes(3) is three zero bytes; array('H') bytes depend on the byte order.
    for bad in (3, True, array("H", [1]), memoryview(array("H", [1]))):
        with pytest.raises(TypeError):
            c.raw_request(0x41, bad)  # type: ignore[arg-type]
    assert requests == []


def test_numpy_values_and_buffers() -> None:
    np = pytest.importorskip("numpy")

    def script(i: int, frame: bytes) -> list[tuple[float, bytes]]:
        if frame[1] in (5, 6):
            return [(0, frame)]
        if frame[1] in (15, 16):
            return [(0, rtu(frame[:6]))]
        return [(0, rtu(bytes((frame[0], 3)) + registers([40000, 1])))]

    with RawPty(script) as pty, pymb.RtuClient(pty.port, 115200, slave=1, timeout=1) as c:
        c.write_coils(0, np.array([True, False, True]))  # numpy bools are bools
        c.write_coil(np.int64(2), np.True_)
        c.write_register(np.uint16(3), np.uint16(4))
        c.write_registers(np.int64(4), np.array([5, 6], dtype=np.uint16))
        assert list(c.read_holding_registers(np.int64(0), np.int32(2))) == [40000, 1]
        assert pty.requests[0][:8] == bytes((1, 15, 0, 0, 0, 3, 1, 0b101))
        assert pty.requests[1][:6] == bytes((1, 5, 0, 2, 0xFF, 0))
        assert pty.requests[2][:6] == bytes((1, 6, 0, 3, 0, 4))
        n = len(pty.requests)
        # A signed or byte-swapped destination would turn 40000 into another number.
        for dtype in (np.int16, np.dtype(">u2"), np.float16, np.uint32):
            with pytest.raises(pymb.InvalidArgument):
                c.read_holding_registers_into(0, np.zeros(2, dtype=dtype))
        with pytest.raises(pymb.InvalidArgument):
            c.read_holding_registers_into(0, memoryview(bytearray(4)).cast("h"))
        for unordered in ({1, 0}, {0: 1}):
            with pytest.raises(TypeError):
                c.write_coils(0, unordered)  # type: ignore[arg-type]
            with pytest.raises(TypeError):
                c.write_registers(0, unordered)  # type: ignore[arg-type]
        with pytest.raises(pymb.InvalidArgument):
            c.write_register(0, np.float64(1.0))
        assert len(pty.requests) == n
        out = np.zeros(2, dtype=np.uint16)
        c.read_holding_registers_into(0, out)
        assert out.tolist() == [40000, 1]


def test_connect_failures_name_their_cause_and_leave_nothing_open() -> None:
    # In a process of its own, so that no other test's thread opens or
    # closes descriptors while they are counted.
    import subprocess
    import sys

    code = """
import gc, os, socket
import pymb

def fds():
    return len(os.listdir("/proc/self/fd"))

nowhere = socket.socket()
nowhere.bind(("127.0.0.1", 0))  # bound, never listening: refused
port = nowhere.getsockname()[1]
before = fds()
cases = [
    (pymb.TcpClient("no-such-host.invalid", 502, timeout=1), "cannot resolve the host name"),
    (pymb.TcpClient("127.0.0.1", port, timeout=1), "connection refused"),
    (pymb.RtuClient("/dev/null"), "not a serial port"),
    (pymb.RtuClient("/dev/pymb-no-such-port"), "no such port"),
]
for client, why in cases:
    try:
        client.connect()
    except pymb.ModbusConnectionError as e:
        assert why in str(e), (why, str(e))
    else:
        raise AssertionError("connected")
    assert not client.connected and client.fileno() == -1
del cases, client
gc.collect()
assert fds() == before, (before, fds())
print("ok")
"""
    out = subprocess.run([sys.executable, "-W", "error::ResourceWarning", "-c", code],
                         capture_output=True, text=True, timeout=60,
                         cwd=str(Path(__file__).resolve().parent.parent))
    assert out.stdout.strip() == "ok", out.stderr


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


# -- against pymodbus as the server -------------------------------------------------------


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
        tid, unit, _pdu = _tcp_req(adu)
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


def test_dropped_tcp_client_is_closed_and_a_never_connected_one_is_silent() -> None:
    with RawTcp(lambda i, adu: []) as peer:
        with warnings.catch_warnings(record=True) as w:
            warnings.simplefilter("always")
            idle = pymb.TcpClient("127.0.0.1", peer.port, slave=1)
            del idle
            gc.collect()
            assert not [x for x in w if issubclass(x.category, ResourceWarning)]
            c = pymb.TcpClient("127.0.0.1", peer.port, slave=1)
            c.connect()
            fd = c.fileno()
            inode = os.readlink(f"/proc/self/fd/{fd}")
            del c
            gc.collect()
        assert any(issubclass(x.category, ResourceWarning) for x in w)
        try:
            still = os.readlink(f"/proc/self/fd/{fd}") == inode
        except OSError:
            still = False
        assert not still


@pytest.mark.parametrize("transport", ["rtu", "tcp", "rtu-over-tcp"])
def test_raw_request_with_a_wrong_response_length_says_so(transport: str) -> None:
    data = bytes(range(30))

    def script(i: int, frame: bytes) -> list[tuple[float, bytes]]:
        if transport == "tcp":
            tid, unit, pdu = _tcp_req(frame)
            return [(0, mbap(tid, unit, bytes((pdu[0],)) + data))]
        return [(0, rtu(bytes((frame[0], frame[1])) + data))]

    peer_cm = RawPty(script) if transport == "rtu" else RawTcp(
        script, rtu_frames=transport == "rtu-over-tcp")
    with peer_cm as peer, _client(transport, peer.port, timeout=0.3) as c:
        assert c.raw_request(0x41, response_length=30) == data
        for wrong in (10, 31, 200):
            with pytest.raises(pymb.ProtocolError, match="length"):
                c.raw_request(0x41, response_length=wrong)
        c.timeout = 2
        assert c.raw_request(0x41) == data
