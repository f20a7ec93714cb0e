"""The client's calls: interrupted by signals, their arguments checked
before any I/O, their descriptors and locks released."""

from __future__ import annotations

import gc
import math
import os
import signal
import sys
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
from wire_peers import RawPty, RawTcp, tcp_request

import pymb


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
        reply = (mbap(tcp_request(frame)[0], 1, body) if transport == "tcp"
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
            tid, unit, pdu = tcp_request(frame)
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


def _hook_calls_while_waiting(transport: str, in_thread: bool) -> int:
    """How often a read's 0.4 s wait on a silent peer called into Python's
    signal hook (``pymb_py_interrupted``), the client opened and used in the
    main thread or in another one."""
    calls = [0]

    def profile(frame: Any, event: str, arg: object) -> None:
        if event == "call" and frame.f_code.co_name == "pymb_py_interrupted":
            calls[0] += 1

    def read() -> None:
        sys.setprofile(profile)
        try:
            with _client(transport, peer.port, timeout=0.4) as c, \
                    pytest.raises(pymb.ModbusTimeout):
                c.read_holding_registers(0, 1)
        finally:
            sys.setprofile(None)

    peer_cm = RawPty(lambda i, f: []) if transport == "rtu" else RawTcp(lambda i, f: [])
    with peer_cm as peer:
        if in_thread:
            t = threading.Thread(target=read)
            t.start()
            t.join(30)
        else:
            read()
    return calls[0]


@pytest.mark.parametrize("transport", ["rtu", "tcp"])
def test_a_line_opened_off_the_main_thread_waits_without_calling_into_python(
        transport: str) -> None:
    # Signal handlers run in the main thread only: there the wait calls in
    # (every 50 ms at most), elsewhere it has nothing to call in for, and a
    # daemon thread's call could meet the interpreter's shutdown.
    assert _hook_calls_while_waiting(transport, in_thread=False) >= 3
    assert _hook_calls_while_waiting(transport, in_thread=True) == 0
