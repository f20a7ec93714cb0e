"""close() from another thread while a request waits on the line: the
waiter gets a ModbusConnectionError within a slice of the wait (50 ms), not
at its timeout; the client is then closed (use after close is a clear
error) and connects again. Every transport, against real peers that stay
silent: a pseudo-terminal, TCP and UDP on 127.0.0.1."""

from __future__ import annotations

import errno
import socket
import struct
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import pytest
from peerkit import Reply, mbap, registers, rtu, rtu_crc_ok
from wire_peers import RawPty, RawTcp, tcp_request

import pymb
from pymb.client.core import line_lock, stop_waiting

TIMEOUT = 5.0  #: the waiting request's own timeout: close() must not wait for it
PROMPT = 1.5  #: what "at once" may take on a loaded machine (50 ms unloaded)


def rtu_script(_: int, frame: bytes) -> Reply:
    """Slave 1's holding register N reads N; slave 9 never answers."""
    if not rtu_crc_ok(frame) or frame[0] != 1:
        return []
    address = struct.unpack(">H", frame[2:4])[0]
    return [(0.0, rtu(bytes((1, 3)) + registers([address])))]


def ascii_script(_: int, frame: bytes) -> Reply:
    """rtu_script's device speaking Modbus ASCII ([MB-SL] 2.5.2: hex, LRC)."""
    body = bytes.fromhex(frame.strip()[1:].decode())
    if body[0] != 1:
        return []
    reply = bytes((1, 3)) + registers([struct.unpack(">H", body[2:4])[0]])
    return [(0.0, b":" + (reply + bytes((-sum(reply) & 0xFF,))).hex().upper().encode()
             + b"\r\n")]


def tcp_script(_: int, adu: bytes) -> Reply:
    tid, unit, pdu = tcp_request(adu)
    if unit != 1:
        return []
    return [(0.0, mbap(tid, unit, pdu[:1] + registers([struct.unpack(">H", pdu[1:3])[0]])))]


@contextmanager
def silent_udp() -> Iterator[int]:
    """A UDP port on 127.0.0.1 that takes datagrams and never answers."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        yield s.getsockname()[1]


@contextmanager
def client(kind: str) -> Iterator[pymb.Client]:
    """A connected client of ``kind`` to a peer where slave 9 is silent."""
    if kind == "rtu" or kind == "ascii":
        with RawPty(rtu_script if kind == "rtu" else ascii_script) as peer:
            serial = pymb.RtuClient if kind == "rtu" else pymb.AsciiClient
            with serial(peer.port, 115200, slave=9, timeout=TIMEOUT) as c:
                yield c
    elif kind == "udp":
        with silent_udp() as port, pymb.UdpClient("127.0.0.1", port, slave=9,
                                                   timeout=TIMEOUT, retries=0) as c:
            yield c
    else:
        framing = kind == "rtu-over-tcp"
        with RawTcp(rtu_script if framing else tcp_script, rtu_frames=framing) as peer:
            cls: Callable[..., pymb.Client] = (pymb.RtuOverTcpClient if framing
                                               else pymb.TcpClient)
            with cls("127.0.0.1", peer.port, slave=9, timeout=TIMEOUT) as c:
                yield c


def close_while_waiting(c: pymb.Client, call: Callable[[], object]) -> BaseException:
    """Start ``call`` in a thread, close ``c`` from here once it waits; the
    error the call ended with (close() and the call both end promptly)."""
    out: list[BaseException] = []

    def wait() -> None:
        try:
            call()
        except BaseException as e:  # what the test looks at
            out.append(e)

    t = threading.Thread(target=wait)
    t.start()
    lock, deadline = line_lock(c), time.monotonic() + 30
    while lock.acquire(blocking=False):  # (a loaded machine may take a while to start it)
        lock.release()
        assert time.monotonic() < deadline, "the call never took the line"
        time.sleep(0.01)
    time.sleep(0.1)  # the call holds the line: its request on the wire, its reply awaited
    t0 = time.monotonic()
    c.close()
    took = time.monotonic() - t0
    t.join(TIMEOUT + 5)
    assert not t.is_alive()
    assert took < PROMPT, f"close() waited {took:.2f} s for the request's timeout"
    assert len(out) == 1, "the call returned a value after its client was closed"
    return out[0]


@pytest.mark.parametrize("kind", ["rtu", "ascii", "tcp", "rtu-over-tcp", "udp"])
def test_close_ends_a_request_another_thread_waits_on(kind: str) -> None:
    with client(kind) as c:
        e = close_while_waiting(c, lambda: c.read_holding_registers(4, 1))
        assert isinstance(e, pymb.ModbusConnectionError), repr(e)
        assert "the client was closed while this request waited" in str(e)
        assert e.errno == errno.ECANCELED
        assert "read_holding_registers(slave=9, address=4, count=1)" in str(e)
        assert not c.connected
        with pytest.raises(pymb.ModbusConnectionError, match="not connected"):
            c.read_holding_registers(4, 1)
        if kind != "udp":  # a peer that answers slave 1: the client works again
            c.connect()
            assert list(c.read_holding_registers(4, 1, slave=1)) == [4]


def test_close_ends_a_drain_and_a_write_too() -> None:
    with client("rtu") as c:
        c.slave = 9
        e = close_while_waiting(c, lambda: c.write_register(3, 7))
        assert isinstance(e, pymb.ModbusConnectionError)
        assert "write_register" in str(e)
        c.connect()
        e = close_while_waiting(c, lambda: c.drain(quiet=TIMEOUT, limit=TIMEOUT))
        assert isinstance(e, pymb.ModbusConnectionError)
        assert "drain" in str(e)


def test_sixteen_threads_on_one_client_and_a_close_among_them() -> None:
    # 16 threads read registers tagged with their address; one of them asks
    # a silent slave now and then. Every answer is the caller's own; the
    # close from here ends them all promptly, each with its answer or a
    # ModbusConnectionError, none hung.
    with RawTcp(tcp_script) as peer, \
            pymb.TcpClient("127.0.0.1", peer.port, slave=1, timeout=TIMEOUT) as c:
        wrong: list[tuple[int, list[int]]] = []
        ended: list[BaseException] = []
        done = [0]
        stop = threading.Event()

        def reader(k: int) -> None:
            i = 0
            asked = False
            try:
                while not stop.is_set():
                    address = 1000 * k + i % 500
                    slave = 1
                    if k == 0 and not asked and done[0] > 200:
                        slave, asked = 9, True
                    got = list(c.read_holding_registers(address, 1, slave=slave))
                    if got != [address]:
                        wrong.append((address, got))
                    done[0] += 1
                    i += 1
            except pymb.ModbusError as e:
                ended.append(e)

        threads = [threading.Thread(target=reader, args=(k,)) for k in range(16)]
        for t in threads:
            t.start()
        deadline = time.monotonic() + 30
        while not any(r[6] == 9 for r in peer.requests) and time.monotonic() < deadline:
            time.sleep(0.01)  # 200 reads, then the silent slave's request on the wire
        time.sleep(0.2)
        t0 = time.monotonic()
        c.close()
        stop.set()
        for t in threads:
            t.join(TIMEOUT + 5)
        assert not any(t.is_alive() for t in threads)
        assert time.monotonic() - t0 < PROMPT + 1
        assert wrong == []
        assert done[0] > 200
        assert all(isinstance(e, pymb.ModbusConnectionError) for e in ended), ended



def test_a_write_whose_turn_comes_after_the_close_began_is_not_sent() -> None:
    # close() from another thread while a request holds the line stops that
    # request first (stop_waiting), then waits for the line's lock; a write
    # that gets the lock before the close must not go out: the device would
    # do it while its caller is told the client was closed.
    def script(_: int, adu: bytes) -> Reply:
        tid, unit, pdu = tcp_request(adu)
        return [(0.0, mbap(tid, unit, pdu))]  # a write's echo

    with RawTcp(script) as peer, \
            pymb.TcpClient("127.0.0.1", peer.port, slave=1, timeout=TIMEOUT) as c:
        out: list[object] = []

        def write() -> None:
            try:
                c.write_register(3, 7)
                out.append("written")
            except pymb.ModbusError as e:
                out.append(e)

        writer = threading.Thread(target=write)
        with line_lock(c):  # the request on the line, as far as the writer can tell
            writer.start()
            time.sleep(0.1)  # (waiting for the lock or not yet: the same outcome)
            stop_waiting(c)  # what close() from another thread does first
        writer.join(TIMEOUT + 5)
        assert not writer.is_alive()
        c.close()
        assert [r for r in peer.requests if r[7] == 6] == [], "the write went out"
        e = out[0]
        assert isinstance(e, pymb.ModbusConnectionError), repr(e)
        assert e.errno == errno.ECANCELED
        assert "write_register(slave=1, address=3, count=1)" in str(e)
        assert "the client was closed before this request was sent" in str(e)
