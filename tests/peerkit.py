"""What the tests' scripted peers (peers.py, wire_peers.py) are made of: the
frames of the Modbus specifications, built here and not by pymb, and one
daemon thread serving the device's end of a real pseudo-terminal or a TCP
socket on 127.0.0.1 until ``stop()``. A peer is a context manager: its
thread runs inside the ``with`` and is stopped (and its descriptors closed)
on the way out.
"""

from __future__ import annotations

import os
import select
import socket
import struct
import threading
import time
import tty
from contextlib import suppress
from types import TracebackType
from typing import Self

from reference import crc

#: What a peer sends for one request, and when: [(delay_seconds, raw bytes), ...].
Reply = list[tuple[float, bytes]]


def rtu(frame: bytes) -> bytes:
    """An RTU frame: ``frame`` (address + PDU) and its CRC ([MB-SL] 6.2.2)."""
    return frame + crc(frame)


def rtu_crc_ok(frame: bytes) -> bool:
    """Whether an RTU frame's last two bytes are the CRC of the rest."""
    return len(frame) >= 3 and crc(frame[:-2]) == frame[-2:]


def mbap(tid: int, unit: int, pdu: bytes, *, proto: int = 0, length: int | None = None) -> bytes:
    """A Modbus TCP ADU ([MB-TCP] 3.1.3); ``proto`` and ``length`` can lie."""
    n = len(pdu) + 1 if length is None else length
    return struct.pack(">HHHB", tid, proto, n, unit) + pdu


def split_mbap(buf: bytes) -> tuple[list[bytes], bytes]:
    """The whole ADUs at the start of ``buf`` (by the MBAP length field), and the rest."""
    out = []
    while len(buf) >= 7:
        (length,) = struct.unpack(">H", buf[4:6])
        if len(buf) < 6 + length:
            break
        out.append(buf[:6 + length])
        buf = buf[6 + length:]
    return out, buf


def registers(values: list[int]) -> bytes:
    """The data of a read-registers reply: byte count, then big-endian words."""
    return bytes((2 * len(values),)) + struct.pack(f">{len(values)}H", *values)


class ThreadedPeer:
    """A peer served by one daemon thread (``_run``, which returns soon after
    ``_stop`` is set); started by ``with``, stopped by ``stop()``."""

    def __init__(self) -> None:
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        raise NotImplementedError

    def _close(self) -> None:
        """Release what the peer holds, once its thread has ended."""

    def stop(self) -> None:
        """End the thread (within 5 s) and release the descriptors, once."""
        if self._stop.is_set():
            return
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(5)
        self._close()

    def __enter__(self) -> Self:
        self._thread.start()
        return self

    def __exit__(self, et: type[BaseException] | None, ev: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.stop()


class PtyPeerBase(ThreadedPeer):
    """The device's end of a raw pseudo-terminal; ``port`` is the path a
    master opens. Subclasses say what the bytes received so far mean
    (``received``) and what a silence on the line does to them (``silence``)."""

    def __init__(self) -> None:
        super().__init__()
        self.master, self._slave = os.openpty()
        tty.setraw(self.master)
        tty.setraw(self._slave)
        self.port = os.ttyname(self._slave)
        self.written = 0  #: pieces written by ``send`` (what a test can wait for)

    def quiet_ms(self, buf: bytes) -> int:
        """How long the line must be silent (ms) before ``silence(buf)``."""
        return 50

    def silence(self, buf: bytes) -> bytes:
        """The line went quiet with ``buf`` pending: by default it ends any partial frame."""
        return b""

    def received(self, buf: bytes) -> bytes:
        """Handle the bytes received so far; return what is left pending."""
        return buf

    def send(self, reply: Reply) -> None:
        """Write each piece of ``reply`` after its delay (a closed line is not an error)."""
        for delay, data in reply:
            if delay:
                time.sleep(delay)
            with suppress(OSError):
                os.write(self.master, data)
            self.written += 1

    def _run(self) -> None:
        poller = select.poll()  # poll, not select: any descriptor number
        poller.register(self.master, select.POLLIN)
        buf = b""
        while not self._stop.is_set():
            if not poller.poll(self.quiet_ms(buf)):
                buf = self.silence(buf)
                continue
            try:
                buf += os.read(self.master, 512)
            except OSError:
                return
            buf = self.received(buf)

    def _close(self) -> None:
        for fd in (self.master, self._slave):
            with suppress(OSError):
                os.close(fd)


class TcpPeerBase(ThreadedPeer):
    """A TCP server on 127.0.0.1 (``port``, or an ephemeral one: ``address``, ``port``)
    serving one connection at a time: each request ``split`` out of the
    stream gets ``answer(request)``, each piece sent after its delay."""

    def __init__(self, port: int = 0) -> None:
        super().__init__()
        self._sock = socket.create_server(("127.0.0.1", port))
        self._sock.settimeout(0.05)
        self.address: tuple[str, int] = self._sock.getsockname()
        self.port = self.address[1]

    def split(self, buf: bytes) -> tuple[list[bytes], bytes]:
        """The whole requests at the start of ``buf``, and the rest: MBAP framing."""
        return split_mbap(buf)

    def answer(self, request: bytes) -> Reply:
        raise NotImplementedError

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
                self._serve(conn)

    def _serve(self, conn: socket.socket) -> None:
        buf = b""
        while not self._stop.is_set():
            try:
                data = conn.recv(1024)
            except TimeoutError:
                continue
            except OSError:
                return
            if not data:
                return
            requests, buf = self.split(buf + data)
            for request in requests:
                for delay, out in self.answer(request):
                    if delay:
                        time.sleep(delay)
                    with suppress(OSError):
                        conn.sendall(out)

    def _close(self) -> None:
        self._sock.close()
