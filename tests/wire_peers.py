"""Hostile peers for the wire-level tests, written from the Modbus
specifications and nothing of pymb's (their frames and bitwise CRC are
tests/peerkit.py's): a raw TCP responder that parses MBAP itself, a raw RTU
responder on a pseudo-terminal or a TCP socket that frames requests by the
line's silence, an RTU line with a real line's timing, a UDP responder on
127.0.0.1 (one datagram a frame), and two servers in
their own processes: Debian's libmodbus (tests/libmodbus_server.c, built here
with cc) and pymodbus (tests/pymodbus_server.py). Each scripted peer hands
every request to a script that returns what to send back and when:
``[(delay_seconds, raw bytes), ...]``.
"""

from __future__ import annotations

import os
import select
import shutil
import socket
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from pathlib import Path

import pytest
from peerkit import PtyPeerBase, Reply, TcpPeerBase, ThreadedPeer, mbap, registers, rtu

HERE = Path(__file__).resolve().parent

Script = Callable[[int, bytes], Reply]


def tcp_request(adu: bytes) -> tuple[int, int, bytes]:
    """A Modbus TCP request's transaction id, unit id and PDU."""
    tid, _, _, unit = struct.unpack(">HHHB", adu[:7])
    return tid, unit, adu[7:]


def answer_read(adu: bytes, values: list[int]) -> bytes:
    """The Modbus TCP reply to a read request ``adu``: ``values`` as its registers."""
    tid, unit, pdu = tcp_request(adu)
    return mbap(tid, unit, bytes((pdu[0],)) + registers(values))


class RawTcp(TcpPeerBase):
    """A TCP responder: each request goes to ``script(index, request)`` where
    request is the whole ADU (MBAP framing) or, with ``rtu_frames``, each
    segment received (the client writes an RTU frame at once); ``requests``
    keeps them all."""

    def __init__(self, script: Script, *, rtu_frames: bool = False, port: int = 0) -> None:
        super().__init__(port)
        self.script = script
        self.rtu_frames = rtu_frames
        self.requests: list[bytes] = []

    def split(self, buf: bytes) -> tuple[list[bytes], bytes]:
        if self.rtu_frames:
            return ([buf] if buf else []), b""
        return super().split(buf)

    def answer(self, request: bytes) -> Reply:
        self.requests.append(request)
        return self.script(len(self.requests) - 1, request)


class RawPty(PtyPeerBase):
    """An RTU responder on a pseudo-terminal: a request ends when the line
    has been silent for 5 ms; ``script(index, frame)`` answers it."""

    def __init__(self, script: Script) -> None:
        super().__init__()
        self.script = script
        self.requests: list[bytes] = []

    def quiet_ms(self, buf: bytes) -> int:
        return 5 if buf else 50

    def silence(self, buf: bytes) -> bytes:
        if buf:
            self.requests.append(buf)
            self.send(self.script(len(self.requests) - 1, buf))
        return b""


def build_libmodbus_server(tmp: Path) -> Path:
    """Compile tests/libmodbus_server.c against Debian's libmodbus."""
    cc = shutil.which("cc") or "gcc"
    flags = subprocess.run(["pkg-config", "--cflags", "--libs", "libmodbus"], check=True,
                           capture_output=True, text=True).stdout.split()
    exe = tmp / "libmodbus_server"
    subprocess.run([cc, "-O1", "-o", str(exe), str(HERE / "libmodbus_server.c"), *flags],
                   check=True)
    return exe


@contextmanager
def _ready_server(argv: list[str], **popen: object) -> Iterator[str]:
    """Run a server process until the block ends (stopped by its PID); yields
    what it printed after READY on its first line (a port or a pty path)."""
    proc: subprocess.Popen[str] = subprocess.Popen(  # type: ignore[call-overload]
        argv, stdout=subprocess.PIPE, text=True, **popen)
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline().split()
        assert line, "the server printed nothing"
        assert line[0] == "READY", line
        yield line[1]
    finally:
        proc.kill()
        proc.wait(10)


@contextmanager
def libmodbus_server(exe: Path, mode: str) -> Iterator[str]:
    """Run the libmodbus server in ``mode``; yields what it printed after
    READY (a port or a pty path). Stopped by its PID."""
    with _ready_server([str(exe), mode]) as where:
        yield where


@contextmanager
def pymodbus_server(mode: str, *args: str) -> Iterator[int]:
    """Run tests/pymodbus_server.py (``tcp``, ``rtu-over-tcp``, or ``tls DIR``)
    in its own process; yields its port. Stopped by its PID."""
    with _ready_server([sys.executable, str(HERE / "pymodbus_server.py"), mode, *args],
                       stderr=subprocess.DEVNULL) as port:
        yield int(port)


@contextmanager
def pymodbus_peer(mode: str) -> Iterator[str]:
    """tests/pymodbus_server.py in ``mode`` as :func:`pymodbus_server`, for
    ``ascii`` (yields the pseudo-terminal's path) and ``udp`` (the port, as
    text) too; the test is skipped where pymodbus is missing."""
    pytest.importorskip("pymodbus")
    with _ready_server([sys.executable, str(HERE / "pymodbus_server.py"), mode],
                       stderr=subprocess.DEVNULL) as where:
        yield where


class EmulatedLine(PtyPeerBase):
    """An RTU device behind a pseudo-terminal that keeps a real line's timing
    at ``baud`` (8N1): a request is complete after its 8 bytes (function
    0x03 only), its wire time and t3.5 pass before the reply's first byte can
    arrive, and each reply's one register is the address asked for (so a
    stale reply cannot pass for the right one).
    ``repeat_after``: like a repeater that sends every reply twice, the copy
    follows that many seconds after the original, in 1 ms pieces (bytes on a
    wire arrive one by one, not at once)."""

    def __init__(self, baud: int, repeat_after: float | None = None) -> None:
        super().__init__()
        self.char = 10 / baud
        self.t35 = 3.5 * 11 / baud if baud <= 19200 else 0.00175
        self.repeat_after = repeat_after
        self.count = 0

    def _sleep_until(self, t: float) -> None:
        while (left := t - time.perf_counter()) > 0:
            time.sleep(min(left, 0.0005) if left < 0.002 else left - 0.001)

    def received(self, buf: bytes) -> bytes:
        arrived = time.perf_counter()
        while len(buf) >= 8:
            frame, buf = buf[:8], buf[8:]
            if rtu(frame[:6]) != frame:
                continue
            asked = frame[2] << 8 | frame[3]
            reply = rtu(bytes((frame[0], 3)) + registers([asked]))
            self.count += 1
            # the request's own wire time, t3.5, then the first character
            self._sleep_until(arrived + (8 + 1) * self.char + self.t35)
            with suppress(OSError):
                os.write(self.master, reply)
            end = time.perf_counter()
            if self.repeat_after is None:
                continue
            start = end + self.repeat_after
            step = max(1, round(0.001 / self.char))
            for k in range(0, len(reply), step):
                self._sleep_until(start + k * self.char)
                with suppress(OSError):
                    os.write(self.master, reply[k:k + step])
        return buf


class UdpPeer(ThreadedPeer):
    """A device on a UDP port of 127.0.0.1: ``script(index, request)`` says
    which datagrams to send back for each request datagram, and when."""

    def __init__(self, script: Callable[[int, bytes], Reply]) -> None:
        super().__init__()
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.port: int = self.sock.getsockname()[1]
        self.script = script
        self.requests: list[bytes] = []
        self._senders: list[threading.Thread] = []

    def _run(self) -> None:
        while not self._stop.is_set():
            if not select.select([self.sock], [], [], 0.05)[0]:
                continue
            data, peer = self.sock.recvfrom(1024)
            self.requests.append(data)
            reply = self.script(len(self.requests) - 1, data)
            t = threading.Thread(target=self._send, args=(reply, peer), daemon=True)
            self._senders.append(t)
            t.start()

    def _send(self, reply: Reply, peer: tuple[str, int]) -> None:
        for delay, data in reply:
            if delay:
                time.sleep(delay)
            if not self._stop.is_set():
                self.sock.sendto(data, peer)

    def _close(self) -> None:
        for t in self._senders:
            t.join(5)
        self.sock.close()


def udp_read_reply(req: bytes, values: list[int], *, tid: int | None = None,
                   unit: int | None = None) -> bytes:
    """The datagram answering the read request datagram ``req`` with ``values``
    (its transaction id and unit id unless ``tid``, ``unit`` say others)."""
    t = int.from_bytes(req[:2], "big") if tid is None else tid
    u = req[6] if unit is None else unit
    return mbap(t, u, bytes((req[7],)) + registers(values))
