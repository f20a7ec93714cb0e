"""Hostile peers for the wire-level tests, written from the Modbus
specifications and nothing of pymb's (their CRC is the bitwise one of
[MB-SL] 6.2.2): a raw TCP responder that parses MBAP itself, a raw RTU
responder on a pseudo-terminal or a TCP socket that frames requests by the
line's silence, and Debian's libmodbus as a server (tests/libmodbus_server.c,
built here with cc). Each scripted peer hands every request to a script that
returns what to send back and when: ``[(delay_seconds, raw bytes), ...]``.
"""

from __future__ import annotations

import os
import select
import shutil
import socket
import struct
import subprocess
import threading
import time
import tty
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from pathlib import Path

HERE = Path(__file__).resolve().parent

Script = Callable[[int, bytes], "list[tuple[float, bytes]]"]


def crc(data: bytes) -> bytes:
    """CRC-16/MODBUS, bit by bit ([MB-SL] 6.2.2), low byte first."""
    c = 0xFFFF
    for b in data:
        c ^= b
        for _ in range(8):
            c = (c >> 1) ^ 0xA001 if c & 1 else c >> 1
    return bytes((c & 0xFF, c >> 8))


def rtu(frame: bytes) -> bytes:
    """An RTU frame: ``frame`` (address + PDU) and its CRC."""
    return frame + crc(frame)


def mbap(tid: int, unit: int, pdu: bytes, *, proto: int = 0, length: int | None = None) -> bytes:
    """A Modbus TCP ADU ([MB-TCP] 3.1.3); ``proto`` and ``length`` can lie."""
    n = len(pdu) + 1 if length is None else length
    return struct.pack(">HHHB", tid, proto, n, unit) + pdu


def registers(values: list[int]) -> bytes:
    """The data of a read-registers reply: byte count, then big-endian words."""
    return bytes((2 * len(values),)) + struct.pack(f">{len(values)}H", *values)


class RawTcp:
    """A TCP responder: each request (tid, unit, PDU) goes to ``script(index,
    request)`` where request is the whole ADU; ``requests`` keeps them all."""

    def __init__(self, script: Script, *, rtu_frames: bool = False) -> None:
        self.script = script
        self.rtu_frames = rtu_frames
        self.requests: list[bytes] = []
        self._sock = socket.create_server(("127.0.0.1", 0))
        self._sock.settimeout(0.05)
        self.port = self._sock.getsockname()[1]
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _frames(self, buf: bytes) -> tuple[list[bytes], bytes]:
        out = []
        if self.rtu_frames:  # a whole segment is a frame (the client writes one at once)
            return ([buf] if buf else []), b""
        while len(buf) >= 7:
            (length,) = struct.unpack(">H", buf[4:6])
            if len(buf) < 6 + length:
                break
            out.append(buf[:6 + length])
            buf = buf[6 + length:]
        return out, buf

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self._sock.accept()
            except (TimeoutError, OSError):
                continue
            with conn:
                conn.settimeout(0.05)
                # Pieces go out when the script says (no Nagle holding them back).
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                buf = b""
                while not self._stop.is_set():
                    try:
                        data = conn.recv(1024)
                    except TimeoutError:
                        continue
                    except OSError:
                        break
                    if not data:
                        break
                    frames, buf = self._frames(buf + data)
                    for f in frames:
                        self.requests.append(f)
                        for delay, out in self.script(len(self.requests) - 1, f):
                            if delay:
                                time.sleep(delay)
                            with suppress(OSError):
                                conn.sendall(out)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5)
        self._sock.close()


class RawPty:
    """An RTU responder on a pseudo-terminal: a request ends when the line
    has been silent for 5 ms; ``script(index, frame)`` answers it."""

    def __init__(self, script: Script) -> None:
        self.script = script
        self.requests: list[bytes] = []
        self.master, self._slave = os.openpty()
        tty.setraw(self.master)
        tty.setraw(self._slave)
        self.port = os.ttyname(self._slave)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        poller = select.poll()
        poller.register(self.master, select.POLLIN)
        buf = b""
        while not self._stop.is_set():
            if not poller.poll(5 if buf else 50):
                if buf:
                    self.requests.append(buf)
                    frame, buf = buf, b""
                    for delay, out in self.script(len(self.requests) - 1, frame):
                        if delay:
                            time.sleep(delay)
                        with suppress(OSError):
                            os.write(self.master, out)
                continue
            try:
                buf += os.read(self.master, 512)
            except OSError:
                return

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5)
        for fd in (self.master, self._slave):
            with suppress(OSError):
                os.close(fd)


@contextmanager
def raw_tcp(script: Script, *, rtu_frames: bool = False) -> Iterator[RawTcp]:
    peer = RawTcp(script, rtu_frames=rtu_frames)
    try:
        yield peer
    finally:
        peer.stop()


@contextmanager
def raw_pty(script: Script) -> Iterator[RawPty]:
    peer = RawPty(script)
    try:
        yield peer
    finally:
        peer.stop()


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
def libmodbus_server(exe: Path, mode: str) -> Iterator[str]:
    """Run the libmodbus server in ``mode``; yields what it printed after
    READY (a port or a pty path). Stopped by its PID."""
    proc = subprocess.Popen([str(exe), mode], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline().split()
        assert line, line
        assert line[0] == "READY", line
        yield line[1]
    finally:
        proc.kill()
        proc.wait(10)


class EmulatedLine:
    """An RTU device behind a pseudo-terminal that keeps a real line's timing
    at ``baud`` (8N1): a request is complete after its 8 bytes (function
    0x03 only), its wire time and t3.5 pass before the reply's first byte can
    arrive, and each reply's one register is the address asked for (so a
stale reply cannot pass for the right one).
    ``repeat_after``: like a repeater that sends every reply twice, the copy
    follows that many seconds after the original, in 1 ms pieces (bytes on a
    wire arrive one by one, not at once)."""

    def __init__(self, baud: int, repeat_after: float | None = None) -> None:
        self.char = 10 / baud
        self.t35 = 3.5 * 11 / baud if baud <= 19200 else 0.00175
        self.repeat_after = repeat_after
        self.master, self._slave = os.openpty()
        tty.setraw(self.master)
        tty.setraw(self._slave)
        self.port = os.ttyname(self._slave)
        self.count = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _sleep_until(self, t: float) -> None:
        while (left := t - time.perf_counter()) > 0:
            time.sleep(min(left, 0.0005) if left < 0.002 else left - 0.001)

    def _run(self) -> None:
        poller = select.poll()
        poller.register(self.master, select.POLLIN)
        buf = b""
        while not self._stop.is_set():
            if not poller.poll(50):
                buf = b""
                continue
            try:
                buf += os.read(self.master, 512)
            except OSError:
                return
            arrived = time.perf_counter()
            while len(buf) >= 8:
                frame, buf = buf[:8], buf[8:]
                if crc(frame[:6]) != frame[6:]:
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

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5)
        for fd in (self.master, self._slave):
            with suppress(OSError):
                os.close(fd)


@contextmanager
def emulated_line(baud: int, repeat_after: float | None = None) -> Iterator[EmulatedLine]:
    line = EmulatedLine(baud, repeat_after)
    try:
        yield line
    finally:
        line.stop()


@contextmanager
def pymodbus_server(mode: str) -> Iterator[int]:
    """Run tests/pymodbus_server.py (``tcp`` or ``rtu-over-tcp``) in its own
    process; yields its port. Stopped by its PID."""
    import sys

    proc = subprocess.Popen([sys.executable, str(HERE / "pymodbus_server.py"), mode],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline().split()
        assert line, line
        assert line[0] == "READY", line
        yield int(line[1])
    finally:
        proc.kill()
        proc.wait(10)
