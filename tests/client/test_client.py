"""The low-level client against real libmodbus over real pseudo-terminals and
TCP on 127.0.0.1, with a scripted peer (tests/peers.py) to provoke each
error path."""

from __future__ import annotations

import errno
import struct
import subprocess
import sys
import textwrap
import threading
import time
from array import array
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import reference
from conftest import PYMB_ENV, TIMEOUT, wait_until
from peerkit import Reply
from peers import PtyPeer, TcpPeer

import pymb
from pymb import _native

# Client timeout for the error paths: short, so the suite stays fast (longer
# under valgrind, see .ci/valgrind).
T = TIMEOUT

#: What a peer hook returns: (delay, bytes) to send, or None for the normal reply.
HookReply = Reply | None


@pytest.fixture
def peer() -> Iterator[PtyPeer]:
    with PtyPeer() as p:
        yield p


@pytest.fixture
def peer_client(peer: PtyPeer) -> Iterator[pymb.RtuClient]:
    with pymb.RtuClient(peer.port, 19200, slave=40, timeout=T) as c:
        yield c


def reg_request(slave: int, fc: int, addr: int, n: int) -> tuple[int, bytes]:
    return slave, bytes((fc,)) + struct.pack(">HH", addr, n)


# -- CRC ----------------------------------------------------------------------


def test_crc16_known_values() -> None:
    # CRC-16/MODBUS catalogue check value.
    assert pymb.crc16(b"123456789") == 0x4B37
    # CoolPro document, ch. 04: worked CRCs (sent low byte first).
    assert pymb.crc16(bytes.fromhex("280400000001")) == 0x3336
    assert pymb.crc16(bytes.fromhex("2804025FB4")) == 0x71DD
    assert _native.with_crc(bytes.fromhex("280400000001")).hex() == "2804000000013633"
    assert pymb.crc16(b"") == 0xFFFF
    assert pymb.crc16(bytearray(b"123456789")) == pymb.crc16(memoryview(b"123456789"))


def test_crc16_matches_bitwise_reference() -> None:
    for n in (1, 2, 7, 64, 255, 256):
        data = bytes((i * 37 + n) & 0xFF for i in range(n))
        assert pymb.crc16(data) == reference.crc16(data)


# -- reads --------------------------------------------------------------------


def test_read_input_and_holding(peer_client: pymb.RtuClient, peer: PtyPeer) -> None:
    r = peer_client.read_input_registers(0, 8)
    assert isinstance(r, array)
    assert r.typecode == "H"
    assert list(r) == list(range(8))
    h = peer_client.read_holding_registers(10, 3)
    assert list(h) == [70, 77, 84]
    assert peer.requests == [reg_request(40, 4, 0, 8), reg_request(40, 3, 10, 3)]


def test_long_read_is_split_into_maximal_requests(peer_client: pymb.RtuClient,
                                                  peer: PtyPeer) -> None:
    r = peer_client.read_holding_registers(31, 700)
    assert list(r) == [(i * 7) & 0xFFFF for i in range(31, 731)]
    counts = [struct.unpack(">HH", pdu[1:5]) for _, pdu in peer.requests]
    assert counts == [(31, 125), (156, 125), (281, 125), (406, 125), (531, 125), (656, 75)]


def test_read_into_preallocated_buffer(peer_client: pymb.RtuClient) -> None:
    buf = array("H", bytes(2 * 300))
    peer_client.read_input_registers_into(1000, buf)
    assert list(buf) == list(range(1000, 1300))
    with pytest.raises(pymb.InvalidArgument):
        peer_client.read_input_registers_into(0, bytearray(10))


def test_high_slave_addresses_use_pymb_framing(peer: PtyPeer) -> None:
    with pymb.RtuClient(peer.port, 9600, timeout=T) as c:
        for slave in (248, 250, 255):
            r = c.read_holding_registers(31, 130, slave=slave)
            assert list(r) == [(i * 7) & 0xFFFF for i in range(31, 161)]
        assert {s for s, _ in peer.requests} == {248, 250, 255}


def test_slave_250_reply_with_bad_crc_is_refused(peer: PtyPeer) -> None:
    # libmodbus would skip the CRC check here (the reply's address is not the
    # context's slave); pymb must not.
    def corrupt(slave: int, pdu: bytes, normal: bytes | None) -> HookReply:
        frame = bytearray(peer.frame(slave, normal or b""))
        frame[4] ^= 0x01
        return [(0, bytes(frame))]

    peer.hook = corrupt
    with pymb.RtuClient(peer.port, timeout=T, slave=250) as c:
        with pytest.raises(pymb.ProtocolError) as ei:
            c.read_holding_registers(31, 4)
        assert ei.value.reason == "bad CRC"
        peer.hook = None
        assert list(c.read_holding_registers(31, 2)) == [217, 224]


def test_coils_and_discrete_inputs(peer_client: pymb.RtuClient) -> None:
    assert list(peer_client.read_coils(0, 10)) == [1, 0, 0, 1, 0, 0, 1, 0, 0, 1]
    assert list(peer_client.read_discrete_inputs(3, 5)) == [1, 0, 1, 0, 1]
    long = peer_client.read_discrete_inputs(0, 4500)  # split at 2000 bits
    assert list(long) == [i % 2 for i in range(4500)]
    peer_client.write_coil(1, True)
    peer_client.write_coils(20, [1, 1, 0, 1, 0, 0, 0, 0, 1])
    assert list(peer_client.read_coils(0, 2)) == [1, 1]
    assert list(peer_client.read_coils(20, 9)) == [1, 1, 0, 1, 0, 0, 0, 0, 1]


def test_writes_and_the_rest_of_the_surface(peer_client: pymb.RtuClient, peer: PtyPeer) -> None:
    peer_client.write_register(5, 0xBEEF)
    peer_client.write_registers(100, [1, 2, 3, 0xFFFF])
    assert list(peer_client.read_holding_registers(100, 4)) == [1, 2, 3, 0xFFFF]
    assert peer_client.read_holding_registers(5, 1)[0] == 0xBEEF
    peer_client.mask_write_register(5, 0x00FF, 0x1200)
    assert peer_client.read_holding_registers(5, 1)[0] == 0x12EF
    r = peer_client.write_read_registers(200, [9, 8], 199, 4)
    assert list(r) == [(199 * 7) & 0xFFFF, 9, 8, (202 * 7) & 0xFFFF]
    assert peer_client.report_slave_id() == b"\x2a\xffpymb-peer"
    assert peer_client.read_exception_status() == 0x5A
    assert peer_client.raw_request(0x04, struct.pack(">HH", 7, 2)) == b"\x04\x00\x07\x00\x08"
    assert peer.memory.holding[200:202] == [9, 8]


def test_write_echo_must_match(peer_client: pymb.RtuClient, peer: PtyPeer) -> None:
    def wrong_echo(slave: int, pdu: bytes, normal: bytes | None) -> HookReply:
        if pdu[0] == 6:
            return [(0, peer.frame(slave, pdu[:3] + b"\x00\x2b"))]
        return None

    peer.hook = wrong_echo
    with pytest.raises(pymb.ProtocolError) as ei:
        peer_client.write_register(0, 42)
    assert "echo" in str(ei.value)


# -- errors -------------------------------------------------------------------


def test_timeout(peer_client: pymb.RtuClient, peer: PtyPeer) -> None:
    peer.hook = lambda *a: []
    t0 = time.monotonic()
    with pytest.raises(pymb.ModbusTimeout) as ei:
        peer_client.read_input_registers(0, 8)
    assert time.monotonic() - t0 < 5 * T
    e = ei.value
    assert isinstance(e, TimeoutError)
    assert isinstance(e, pymb.ModbusError)
    msg = str(e)
    for part in ("read_input_registers", "slave=40", "address=0", "count=8", peer.port, f"{T:g}"):
        assert part in msg
    assert (e.slave, e.function, e.address, e.count) == (40, 4, 0, 8)


def test_bad_crc(peer_client: pymb.RtuClient, peer: PtyPeer) -> None:
    def bad(slave: int, pdu: bytes, normal: bytes | None) -> HookReply:
        frame = bytearray(peer.frame(slave, normal or b""))
        frame[-1] ^= 0xFF
        return [(0, bytes(frame))]

    peer.hook = bad
    with pytest.raises(pymb.ProtocolError) as ei:
        peer_client.read_input_registers(0, 2)
    assert ei.value.reason == "bad CRC"
    assert "CRC" in str(ei.value)
    assert "received 28 04 04" in str(ei.value)
    assert ei.value.response is not None
    assert ei.value.response[:3] == b"\x28\x04\x04"


def test_wrong_slave(peer_client: pymb.RtuClient, peer: PtyPeer) -> None:
    peer.hook = lambda slave, pdu, normal: [(0, peer.frame(41, normal or b""))]
    with pytest.raises(pymb.ProtocolError) as ei:
        peer_client.read_input_registers(0, 2)
    assert ei.value.reason == "wrong slave"
    assert "another address 41" in str(ei.value)


@pytest.mark.parametrize(
    ("code", "cls"),
    [
        (1, pymb.IllegalFunction),
        (2, pymb.IllegalDataAddress),
        (3, pymb.IllegalDataValue),
        (4, pymb.DeviceFailure),
        (6, pymb.DeviceBusy),
        (0x0B, pymb.GatewayTargetFailed),
    ],
)
def test_exception_codes(peer_client: pymb.RtuClient, peer: PtyPeer, code: int,
                         cls: type[pymb.DeviceException]) -> None:
    peer.hook = lambda slave, pdu, normal: [(0, peer.frame(slave, bytes((pdu[0] | 0x80, code))))]
    with pytest.raises(cls) as ei:
        peer_client.read_holding_registers(0, 1)
    assert ei.value.code == code
    assert isinstance(ei.value, pymb.DeviceException)
    assert f"exception {code:02X}" in str(ei.value)


def test_exception_from_a_real_range_error(peer_client: pymb.RtuClient) -> None:
    with pytest.raises(pymb.IllegalDataAddress):
        peer_client.read_holding_registers(60000, 4)
    # The line is still in step.
    assert list(peer_client.read_input_registers(0, 2)) == [0, 1]


def test_mismatched_reply_length(peer_client: pymb.RtuClient, peer: PtyPeer) -> None:
    # A well-formed reply to a different quantity.
    peer.hook = lambda slave, pdu, normal: [(0, peer.frame(slave, b"\x04\x02\x00\x01"))]
    with pytest.raises(pymb.ProtocolError):
        peer_client.read_input_registers(0, 2)


def test_late_reply_is_never_taken_as_a_later_answer(peer_client: pymb.RtuClient,
                                                      peer: PtyPeer) -> None:
    # The first request is answered after the client gave up; the reply has
    # exactly the shape of the next request's reply, with other data.
    peer.memory.inputs[0:2] = [0xDEAD, 0xBEEF]
    calls = {"n": 0}

    def late_first(slave: int, pdu: bytes, normal: bytes | None) -> HookReply:
        calls["n"] += 1
        if calls["n"] == 1:
            return [(1.4 * T, peer.frame(slave, normal or b""))]
        return None

    peer.hook = late_first
    with pytest.raises(pymb.ModbusTimeout):
        peer_client.read_input_registers(0, 2)
    peer.memory.inputs[0:2] = [1, 2]
    assert list(peer_client.read_input_registers(0, 2)) == [1, 2]


def test_stray_bytes_after_a_reply_do_not_poison_the_next(peer_client: pymb.RtuClient,
                                                           peer: PtyPeer) -> None:
    stale = peer.frame(40, b"\x04\x04\xde\xad\xbe\xef")

    def stray(slave: int, pdu: bytes, normal: bytes | None) -> HookReply:
        return [(0, peer.frame(slave, normal or b"")), (0.01, stale)]

    peer.hook = stray
    written = peer.written
    assert list(peer_client.read_input_registers(0, 2)) == [0, 1]
    wait_until(lambda: peer.written >= written + 2, "the stale frame after the reply", 5)
    peer.hook = None
    assert list(peer_client.read_input_registers(0, 2)) == [0, 1]


def test_truncated_reply(peer_client: pymb.RtuClient, peer: PtyPeer) -> None:
    peer.hook = lambda slave, pdu, normal: [(0, peer.frame(slave, normal or b"")[:5])]
    with pytest.raises(pymb.ModbusTimeout):
        peer_client.read_input_registers(0, 8)
    peer.hook = None
    assert list(peer_client.read_input_registers(0, 3)) == [0, 1, 2]


def test_bad_arguments_never_reach_the_wire(peer_client: pymb.RtuClient, peer: PtyPeer) -> None:
    bad_calls: list[Callable[[], object]] = [
        lambda: peer_client.read_holding_registers(-1, 1),
        lambda: peer_client.read_holding_registers(0, 0),
        lambda: peer_client.read_holding_registers(65535, 2),
        lambda: peer_client.read_holding_registers(0, 1, slave=0),
        lambda: peer_client.read_holding_registers(0, 1, slave=256),
        lambda: peer_client.read_holding_registers(0, 1, slave=True),
        lambda: peer_client.read_holding_registers("0", 1),  # type: ignore[arg-type]
        lambda: peer_client.write_register(0, 70000),
        lambda: peer_client.write_register(0, -1),
        lambda: peer_client.write_registers(0, []),
        lambda: peer_client.write_registers(0, [0] * 124),
        lambda: peer_client.write_registers(0, [1, -5]),
        lambda: peer_client.write_coils(0, [1] * 1969),
        lambda: peer_client.raw_request(0x80),
        lambda: peer_client.raw_request(3, b"x" * 253),
    ]
    for call in bad_calls:
        with pytest.raises(pymb.InvalidArgument) as ei:
            call()
        assert isinstance(ei.value, ValueError)
    assert peer.requests == []


def test_no_slave_set_is_a_clear_error_not_an_abort(peer: PtyPeer) -> None:
    # libmodbus 3.1.6 asserts (aborting the process) when no slave is set.
    with (pymb.RtuClient(peer.port, timeout=T) as c,
          pytest.raises(pymb.InvalidArgument, match="no slave address")):
        c.read_holding_registers(0, 1)


@pytest.mark.parametrize("kwargs", [
    {"baudrate": 12345}, {"baudrate": 0}, {"parity": "X"}, {"data_bits": 9},
    {"stop_bits": 3}, {"timeout": 0}, {"timeout": -1}, {"timeout": "1"},
    {"slave": 300}, {"serial_mode": "rs422"}, {"rts": "sideways"},
])
def test_constructor_validation(kwargs: dict[str, object]) -> None:
    # libmodbus would silently turn 12345 baud into 9600.
    with pytest.raises(pymb.InvalidArgument):
        pymb.RtuClient("/dev/null", **kwargs)  # type: ignore[arg-type]


# -- connection ---------------------------------------------------------------


def test_missing_port_names_the_port() -> None:
    c = pymb.RtuClient("/dev/ttyUSB-does-not-exist", timeout=T, slave=1)
    with pytest.raises(pymb.ModbusConnectionError) as ei:
        c.connect()
    assert ei.value.errno == errno.ENOENT
    assert "/dev/ttyUSB-does-not-exist" in str(ei.value)
    assert isinstance(ei.value, ConnectionError)


def test_not_connected(peer: PtyPeer) -> None:
    c = pymb.RtuClient(peer.port, slave=1, timeout=T)
    with pytest.raises(pymb.ModbusConnectionError, match="not connected"):
        c.read_input_registers(0, 1)


def test_port_in_use_by_another_pymb(peer: PtyPeer) -> None:
    with pymb.RtuClient(peer.port, slave=1, timeout=T):
        other = pymb.RtuClient(peer.port, slave=1, timeout=T)
        with pytest.raises(pymb.ModbusConnectionError, match="in use") as ei:
            other.connect()
        assert ei.value.errno == errno.EBUSY


def test_close_is_idempotent_and_context_manager_reopens(peer: PtyPeer) -> None:
    c = pymb.RtuClient(peer.port, slave=40, timeout=T)
    c.close()
    with c:
        assert c.connected
        assert c.read_input_registers(0, 1)[0] == 0
    assert not c.connected
    c.close()
    c.close()
    with c:
        assert c.read_input_registers(1, 1)[0] == 1
    assert c.connections == 2


def test_unplugged_port_raises_connection_error_then_reconnects() -> None:
    with PtyPeer() as peer, pymb.RtuClient(peer.port, slave=40, timeout=T) as c:
        assert c.read_input_registers(0, 1)[0] == 0
        port = peer.port
        peer.stop()  # the master side disappears, as a pulled USB adapter
        with pytest.raises(pymb.ModbusConnectionError) as ei:
            c.read_input_registers(0, 1)
        assert ei.value.errno == errno.EIO
        assert port in str(ei.value)
        assert not c.connected
        # The pty is gone for good: the automatic reconnect fails clearly too.
        with pytest.raises(pymb.ModbusConnectionError):
            c.read_input_registers(0, 1)


def test_threads_share_one_client(peer_client: pymb.RtuClient) -> None:
    errors: list[BaseException] = []

    def worker(offset: int) -> None:
        try:
            for _ in range(30):
                r = peer_client.read_input_registers(offset, 10)
                assert list(r) == list(range(offset, offset + 10))
        except BaseException as e:  # pragma: no cover - reported below
            errors.append(e)

    threads = [threading.Thread(target=worker, args=(i * 100,)) for i in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    assert errors == []


def test_gil_is_released_while_waiting(peer_client: pymb.RtuClient, peer: PtyPeer) -> None:
    # While one thread waits on a slow reply, another keeps running Python.
    peer.hook = lambda slave, pdu, normal: [(0.15, peer.frame(slave, normal or b""))]
    ticks = 0
    done = threading.Event()

    def spin() -> None:
        nonlocal ticks
        while not done.is_set():
            ticks += 1
            time.sleep(0.001)

    t = threading.Thread(target=spin)
    t.start()
    try:
        peer_client.read_input_registers(0, 2)
    finally:
        done.set()
        t.join()
    assert ticks > 20


# -- TCP ----------------------------------------------------------------------


def test_tcp_reads_writes_and_high_unit_ids() -> None:
    with TcpPeer() as peer, pymb.TcpClient(*peer.address, slave=1, timeout=T) as c:
        assert list(c.read_input_registers(0, 4)) == [0, 1, 2, 3]
        assert len(c.read_holding_registers(0, 700)) == 700
        c.write_register(3, 99)
        assert c.read_holding_registers(3, 1)[0] == 99
        assert list(c.read_input_registers(10, 2, slave=250)) == [10, 11]
        assert list(c.read_input_registers(10, 2, slave=0)) == [10, 11]


def test_tcp_errors() -> None:
    with TcpPeer() as peer, pymb.TcpClient(*peer.address, slave=1, timeout=T) as c:
        peer.hook = lambda slave, pdu, normal: [(0, peer.frame(slave, bytes((pdu[0] | 0x80, 2))))]
        with pytest.raises(pymb.IllegalDataAddress):
            c.read_input_registers(0, 4)
        peer.hook = lambda *a: []
        with pytest.raises(pymb.ModbusTimeout):
            c.read_input_registers(0, 4)
        peer.hook = lambda slave, pdu, normal: [(0, peer.frame(slave + 1, normal or b""))]
        with pytest.raises(pymb.ProtocolError):
            c.read_input_registers(0, 4)
        peer.hook = None
        assert list(c.read_input_registers(0, 2)) == [0, 1]


def test_tcp_connection_refused() -> None:
    with TcpPeer() as peer:
        host, port = peer.address
    c = pymb.TcpClient(host, port, slave=1, timeout=T)
    with pytest.raises(pymb.ModbusConnectionError) as ei:
        c.connect()
    assert ei.value.errno == errno.ECONNREFUSED
    assert f"{host}:{port}" in str(ei.value)


def _high_fd_script(body: str) -> str:
    return textwrap.dedent(f"""
        import os, resource, sys
        sys.path.insert(0, {str(Path(__file__).resolve().parents[1])!r})
        soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
        if hard != resource.RLIM_INFINITY and hard < 1300:
            print("skip: RLIMIT_NOFILE hard limit", hard); sys.exit(0)
        resource.setrlimit(resource.RLIMIT_NOFILE, (max(soft, 1300), hard))
        held = [os.open("/dev/null", os.O_RDONLY) for _ in range(1100)]
        import pymb
        from peers import PtyPeer, TcpPeer
    """) + textwrap.dedent(body)


def _run_script(code: str) -> subprocess.CompletedProcess[str]:
    env = PYMB_ENV
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=60, env=env)


def test_late_reply_is_dropped_on_a_descriptor_above_1024() -> None:
    # The drain after a timeout must work on any descriptor number (it used
    # select(), which stops at FD_SETSIZE: the late reply then got through).
    r = _run_script(_high_fd_script("""
        with PtyPeer() as peer:
            peer.memory.inputs[0:2] = [0xDEAD, 0xBEEF]
            calls = [0]
            def late_first(slave, pdu, normal):
                calls[0] += 1
                return [(0.4, peer.frame(slave, normal))] if calls[0] == 1 else None
            peer.hook = late_first
            with pymb.RtuClient(peer.port, timeout=0.25, slave=40) as c:
                assert c.fileno() >= 1024, c.fileno()
                try:
                    c.read_input_registers(0, 2)
                except pymb.ModbusTimeout:
                    pass
                peer.memory.inputs[0:2] = [1, 2]
                print(list(c.read_input_registers(0, 2)))
    """))
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() in ("[1, 2]",) or r.stdout.startswith("skip"), r.stdout


def test_tcp_on_a_descriptor_above_1024_is_an_error_not_an_abort() -> None:
    r = _run_script(_high_fd_script("""
        with TcpPeer() as peer:
            c = pymb.TcpClient(*peer.address, slave=1, timeout=0.25)
            try:
                c.connect()
            except pymb.ModbusConnectionError as e:
                print("refused:", e)
    """))
    assert r.returncode == 0, r.stderr  # SIGABRT would be -6
    assert "refused:" in r.stdout or r.stdout.startswith("skip"), r.stdout


def test_broadcast_write_waits_the_turnaround(peer: PtyPeer) -> None:
    with pymb.RtuClient(peer.port, timeout=T) as c:
        t0 = time.monotonic()
        c.write_register(7, 1234, slave=0)  # broadcast: no reply expected
        assert time.monotonic() - t0 >= 0.1
        wait_until(lambda: peer.requests, "the broadcast at the peer", 5)
        assert peer.requests[-1] == (0, b"\x06\x00\x07\x04\xd2")
