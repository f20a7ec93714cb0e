"""``pymb serve`` as a child process in front of a scripted peer, and a raw
Modbus TCP client written from the specification (not pymb's)."""

from __future__ import annotations

import re
import signal
import socket
import struct
import subprocess
import threading
from collections.abc import Sequence
from types import TracebackType
from typing import Self

from conftest import PYMB, PYMB_ENV


class Served:
    """``pymb serve ARGS --listen 127.0.0.1:0`` running; ``port`` is where it
    listens (read from its first line). Stopped by SIGTERM on the way out,
    which must end it with exit 0."""

    def __init__(self, *args: str, listen: str = "127.0.0.1:0") -> None:
        where = ["--listen", listen] if listen else []  # "": serve's default
        self.proc = subprocess.Popen([*PYMB, "serve", *args, *where],
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                     env=PYMB_ENV)
        assert self.proc.stdout is not None
        first = self.proc.stdout.readline()
        m = re.search(r"mbaps?://[^ ]*:(\d+) ", first)
        if m is None:
            err = self.proc.stderr.read() if self.proc.stderr else ""
            self.proc.kill()
            raise AssertionError(f"pymb serve did not start: {first!r} {err!r}")
        self.port = int(m.group(1))
        self.first_line = first  #: where clients connect, as serve says it
        self.stderr_lines: list[str] = []
        self._reader = threading.Thread(target=self._read_stderr, daemon=True)
        self._reader.start()
        self.returncode: int | None = None

    def _read_stderr(self) -> None:
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            self.stderr_lines.append(line.rstrip("\n"))

    def stop(self) -> int:
        """SIGTERM, then wait (at most 10 s); the exit code."""
        if self.returncode is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.returncode = self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.returncode = self.proc.wait(5)
            self._reader.join(5)
        return self.returncode

    def __enter__(self) -> Self:
        return self

    def __exit__(self, et: type[BaseException] | None, ev: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.stop()


def mbap(tid: int, unit: int, pdu: bytes) -> bytes:
    """A Modbus TCP request ([MB-TCP] 3.1.3)."""
    return struct.pack(">HHHB", tid, 0, len(pdu) + 1, unit) + pdu


class RawClient:
    """A blocking Modbus TCP client on a plain socket: sends frames, reads
    whole replies by their MBAP length."""

    def __init__(self, port: int, *, timeout: float = 10.0) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=timeout)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.buf = b""

    def send(self, data: bytes) -> None:
        self.sock.sendall(data)

    def reply(self) -> tuple[int, int, bytes]:
        """The next reply: (transaction id, unit, PDU)."""
        while True:
            if len(self.buf) >= 6:
                (n,) = struct.unpack(">H", self.buf[4:6])
                if len(self.buf) >= 6 + n:
                    frame, self.buf = self.buf[:6 + n], self.buf[6 + n:]
                    tid, proto, _length, unit = struct.unpack(">HHHB", frame[:7])
                    assert proto == 0, frame.hex(" ")
                    return tid, unit, frame[7:]
            data = self.sock.recv(4096)
            if not data:
                raise ConnectionError("closed by the server")
            self.buf += data

    def ask(self, tid: int, unit: int, pdu: bytes) -> bytes:
        """One request, its reply's PDU (its tid and unit checked)."""
        self.send(mbap(tid, unit, pdu))
        rtid, runit, rpdu = self.reply()
        assert (rtid, runit) == (tid, unit), (rtid, runit, tid, unit)
        return rpdu

    def closed_by_server(self, timeout: float = 10.0) -> bool:
        """Whether the server closes the connection (EOF) within ``timeout``."""
        self.sock.settimeout(timeout)
        try:
            while True:
                data = self.sock.recv(4096)
                if not data:
                    return True
        except ConnectionResetError:
            return True
        except TimeoutError:
            return False

    def close(self) -> None:
        self.sock.close()


def read_pdu(address: int, count: int, fc: int = 3) -> bytes:
    return struct.pack(">BHH", fc, address, count)


def words(pdu: bytes) -> list[int]:
    """The registers of a read reply PDU."""
    assert pdu[0] in (3, 4, 0x17), pdu.hex(" ")
    return list(struct.unpack(f">{pdu[1] // 2}H", pdu[2:2 + pdu[1]]))


def serve_args(port: str, extra: Sequence[str] = ()) -> list[str]:
    return ["--port", port, "--baud", "115200", "--timeout", "0.5", *extra]
