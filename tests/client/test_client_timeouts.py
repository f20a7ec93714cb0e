"""The response timeout, honoured on every transport, blocking and in
asyncio: a silent peer fails a read with ModbusTimeout after the timeout
(not before, and not long after), and a peer that trickles its reply one
byte at a time cannot hold a call past it. Real peers: a pseudo-terminal,
TCP and UDP on 127.0.0.1."""

from __future__ import annotations

import asyncio
import socket
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import pytest
from peerkit import PtyPeerBase, Reply, mbap, registers, rtu
from wire_peers import RawPty, RawTcp, tcp_request

import pymb
import pymb.aio

TIMEOUT = 0.4
LATE = 1.0  #: how far past the timeout a loaded machine may end the call

KINDS = ["rtu", "ascii", "tcp", "rtu-over-tcp", "udp"]


def trickled(reply: bytes, gap: float = 0.03) -> Reply:
    """``reply`` one byte every ``gap`` seconds (20 registers: 1.35 s and more)."""
    return [(gap, reply[k:k + 1]) for k in range(len(reply))]


def tcp_trickle(_: int, adu: bytes) -> Reply:
    tid, unit, pdu = tcp_request(adu)
    return trickled(mbap(tid, unit, pdu[:1] + registers(list(range(20)))))


def rtu_trickle(_: int, frame: bytes) -> Reply:
    return trickled(rtu(frame[:2] + registers(list(range(20)))))


class AsciiTrickle(PtyPeerBase):
    """A Modbus ASCII device that sends its reply a character at a time."""

    def received(self, buf: bytes) -> bytes:
        if b"\r\n" not in buf:
            return buf
        body = bytes.fromhex(buf.strip()[1:].decode())[:2] + registers(list(range(20)))
        frame = b":" + (body + bytes((-sum(body) & 0xFF,))).hex().upper().encode() + b"\r\n"
        threading.Thread(target=self.send, args=(trickled(frame, 0.02),), daemon=True).start()
        return b""


@contextmanager
def udp_trickle() -> Iterator[int]:
    """A Modbus UDP port that answers every request with datagrams of
    another transaction id, one every 20 ms, for 3 s: never the answer."""
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    stop = threading.Event()

    def serve() -> None:
        s.settimeout(0.05)
        while not stop.is_set():
            try:
                adu, peer = s.recvfrom(600)
            except OSError:
                continue
            tid, unit, pdu = tcp_request(adu)
            end = time.monotonic() + 3
            while time.monotonic() < end and not stop.is_set():
                s.sendto(mbap((tid + 1) & 0xFFFF, unit, pdu[:1] + registers([1])), peer)
                time.sleep(0.02)

    t = threading.Thread(target=serve, daemon=True)
    t.start()
    try:
        yield s.getsockname()[1]
    finally:
        stop.set()
        t.join(5)
        s.close()


@contextmanager
def peer(kind: str, silent: bool) -> Iterator[Callable[..., pymb.Client]]:
    """A peer of ``kind`` (silent, or trickling its replies) and how to make
    a client of it (``timeout=`` and the rest as keywords)."""
    if kind in ("rtu", "ascii"):
        pty = (RawPty(lambda i, f: []) if silent else
               RawPty(rtu_trickle) if kind == "rtu" else AsciiTrickle())
        with pty:
            cls = pymb.RtuClient if kind == "rtu" else pymb.AsciiClient
            yield lambda **kw: cls(pty.port, 115200, slave=1, **kw)
    elif kind == "udp":
        if silent:
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                s.bind(("127.0.0.1", 0))
                port = s.getsockname()[1]
                yield lambda **kw: pymb.UdpClient("127.0.0.1", port, slave=1, retries=0, **kw)
        else:
            with udp_trickle() as port:
                yield lambda **kw: pymb.UdpClient("127.0.0.1", port, slave=1, retries=0, **kw)
    else:
        framing = kind == "rtu-over-tcp"
        script: Callable[[int, bytes], Reply] = (
            (lambda i, f: []) if silent else rtu_trickle if framing else tcp_trickle)
        with RawTcp(script, rtu_frames=framing) as tcp:
            cls2 = pymb.RtuOverTcpClient if framing else pymb.TcpClient
            yield lambda **kw: cls2("127.0.0.1", tcp.port, slave=1, **kw)


def timed(call: Callable[[], object]) -> float:
    t0 = time.monotonic()
    with pytest.raises(pymb.ModbusTimeout):
        call()
    return time.monotonic() - t0


@pytest.mark.parametrize("silent", [True, False], ids=["silent", "trickling"])
@pytest.mark.parametrize("kind", KINDS)
def test_a_read_ends_at_its_timeout(kind: str, silent: bool) -> None:
    with peer(kind, silent) as make, make(timeout=TIMEOUT) as c:
        took = timed(lambda: c.read_holding_registers(0, 20))
        assert TIMEOUT - 0.02 <= took < TIMEOUT + LATE, took


@pytest.mark.parametrize("silent", [True, False], ids=["silent", "trickling"])
@pytest.mark.parametrize("kind", KINDS)
def test_the_same_in_asyncio(kind: str, silent: bool) -> None:
    async def main(blocking: pymb.Client) -> float:
        c = pymb.aio.AsyncClient(blocking)
        async with c:
            loop = asyncio.get_running_loop()
            t0 = loop.time()
            with pytest.raises(pymb.ModbusTimeout):
                await c.read_holding_registers(0, 20)
            return loop.time() - t0

    with peer(kind, silent) as make:
        took = asyncio.run(main(make(timeout=TIMEOUT)))
        assert TIMEOUT - 0.02 <= took < TIMEOUT + LATE, took


@pytest.mark.parametrize("bad", [0, 0.0, -1, -0.5, float("nan"), float("inf"), 3601.0])
@pytest.mark.parametrize("kind", KINDS)
def test_a_timeout_that_is_no_time_is_refused_at_construction(kind: str, bad: float) -> None:
    with peer(kind, True) as make:
        with pytest.raises(pymb.InvalidArgument, match="timeout must be more than 0"):
            make(timeout=bad)
        c = make(timeout=1.0)
        with pytest.raises(pymb.InvalidArgument, match="timeout must be more than 0"):
            c.timeout = bad
        assert c.timeout == 1.0


def test_a_timeout_out_of_range_says_the_range_in_words() -> None:
    with pytest.raises(pymb.InvalidArgument) as e:
        pymb.TcpClient("127.0.0.1", 502, timeout=0)
    assert str(e.value) == "timeout must be more than 0 and at most 3600 seconds, got 0"
    with pytest.raises(pymb.InvalidArgument) as e:
        pymb.TcpClient("127.0.0.1", 502, timeout=1.0, byte_timeout=-1)
    assert str(e.value) == "byte_timeout must be 0..3600 seconds, got -1"
