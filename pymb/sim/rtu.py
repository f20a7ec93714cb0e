"""Modbus RTU on a pseudo-terminal or a real serial port.

Framing: a request is complete when :func:`pymb._native.rtu_request_length`
says so; a function code whose length only silence can tell (or garbage)
ends after 3.5 characters of silence at the line's speed. A frame with a bad
CRC is dropped in silence, as both documents say for the hub and standard
Modbus RTU does. CRCs are pymb's C CRC.

Timing: the reply starts the device's turnaround after the request ends
(the CoolPro's ~8 ms gap, the hub's ``response_delay``). With ``emulate``
each frame also takes its wire time at the line's speed: the reply's last
byte reaches the master at request wire time + max(3.5 characters,
turnaround) + reply wire time, its bytes paced as a real line would (the
1.75 ms floor above 19200 bit/s is only the frame-end timer, not a delay).

The line's speed is the one the master set on the pseudo-terminal (its
termios), read at each frame; a device at another speed stays silent.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import termios
import time
import tty

from pymb import _native
from pymb.sim.bus import IDLE_S, Bus, char_time, reply_gap, silence, sleep_until
from pymb.sim.faults import Fault, framed
from pymb.sim.server import SimServer, readable, write_all

__all__ = ["PtyPort", "RtuServer", "SerialPort", "frame_rtu"]

log = logging.getLogger("pymb.sim")

_INCOMPLETE = _native.FRAME_INCOMPLETE
_MAX_BUFFER = 1024  # garbage beyond this without a pause is dropped
_WRITE_WAIT_S = 0.05  # a full output queue (nobody reading) drops the reply after this

_SPEEDS: dict[int, int] = {}
for _rate in _native.BAUD_RATES:
    _b = getattr(termios, f"B{_rate}", None)
    if _b is not None:
        _SPEEDS[_b] = _rate


def _speed_constant(baud: int) -> int:
    b = getattr(termios, f"B{baud}", None)
    if b is None:
        raise ValueError(f"the serial driver has no speed {baud}")
    return int(b)


def _configure(fd: int, baud: int) -> None:
    """Raw 8N1 at ``baud``."""
    tty.setraw(fd)
    a = termios.tcgetattr(fd)
    a[2] = (a[2] & ~(termios.CSIZE | termios.PARENB | termios.CSTOPB)) | (
        termios.CS8 | termios.CLOCAL | termios.CREAD)
    a[4] = a[5] = _speed_constant(baud)
    termios.tcsetattr(fd, termios.TCSANOW, a)


class PtyPort:
    """A pseudo-terminal pair: the simulator holds the master end and keeps
    the slave end open, so a master can open (and reopen) ``path`` at any
    time and reads never fail while the simulator runs."""

    def __init__(self, baud: int) -> None:
        master, slave = os.openpty()
        try:
            _configure(slave, baud)
            tty.setraw(master)
            os.set_blocking(master, False)
            self.path = os.ttyname(slave)
        except OSError:
            os.close(master)
            os.close(slave)
            raise
        self.fd = master
        self._slave = slave

    def line_baud(self) -> int | None:
        """The speed the master set on the line (None if not a standard one)."""
        return _SPEEDS.get(termios.tcgetattr(self._slave)[5])

    def close(self) -> None:
        """Close both ends: a master on the slave end gets EIO from then on."""
        for fd in (self.fd, self._slave):
            with contextlib.suppress(OSError):
                os.close(fd)


class SerialPort:
    """A real serial port (e.g. a USB RS485 adapter wired to the master's)."""

    def __init__(self, path: str, baud: int) -> None:
        fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        try:
            _configure(fd, baud)
        except (OSError, termios.error):
            os.close(fd)
            raise
        self.fd = fd
        self.path = path
        self._baud = baud

    def line_baud(self) -> int | None:
        """The port's own speed: on a real line a mismatch is physical."""
        return self._baud

    def close(self) -> None:
        """Close the port."""
        with contextlib.suppress(OSError):
            os.close(self.fd)


def frame_rtu(address: int, pdu: bytes, fault: Fault | None) -> bytes:
    """The RTU reply frame (address, PDU, CRC) with the framing faults applied."""
    return framed(lambda a: _native.with_crc(bytes((a,)) + pdu), address, fault)


class RtuServer(SimServer):
    """Serves a bus on a pseudo-terminal (``serial_port`` None) or a real port.

    ``baud``: the line's initial speed. ``emulate``: give each frame its wire
    time. ``link``: a symbolic link kept pointing at the current
    pseudo-terminal (removed while unplugged).
    """

    name = "rtu"

    def __init__(self, bus: Bus, *, baud: int, serial_port: str | None = None,
                 emulate: bool = False, link: str | None = None) -> None:
        super().__init__(bus)
        self.baud = baud
        self.serial_port = serial_port
        self.emulate = emulate
        self.link = link
        self._port: PtyPort | SerialPort | None = None
        self._buf = bytearray()
        self._last = 0.0
        self._line_baud: int | None = baud

    @property
    def path(self) -> str | None:
        """The device path a master opens now (None while unplugged)."""
        return self._port.path if self._port is not None else None

    # -- port ---------------------------------------------------------------------------

    def _open(self) -> None:
        port: PtyPort | SerialPort = (SerialPort(self.serial_port, self.baud)
                                      if self.serial_port else PtyPort(self.baud))
        self._port = port
        self._buf.clear()
        if self.link:
            tmp = f"{self.link}.{os.getpid()}.tmp"
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)
            os.symlink(port.path, tmp)
            os.replace(tmp, self.link)

    def _close(self) -> None:
        if self.link and self._port is not None:
            # Only the link made here: never a file someone put there meanwhile.
            with contextlib.suppress(OSError):
                if os.readlink(self.link) == self._port.path:
                    os.unlink(self.link)
        if self._port is not None:
            self._port.close()
            self._port = None

    # -- serving ------------------------------------------------------------------------

    def _serve_once(self, wake_fd: int) -> None:
        port = self._port
        assert port is not None
        timeout = IDLE_S
        if self._buf:
            timeout = max(0.0, self._last + silence(self._line_baud) - time.perf_counter())
        r = readable([port.fd, wake_fd], timeout)
        if wake_fd in r:
            self._drain_wake()
            return
        if port.fd not in r:
            if self._buf:
                self._on_silence()
            else:
                self.bus.idle()
            return
        try:
            chunk = os.read(port.fd, 4096)
        except BlockingIOError:
            return
        except OSError as e:
            if e.errno == errno.EIO and isinstance(port, PtyPort):
                time.sleep(0.005)  # nobody on the slave end yet
                return
            log.error("%s: read failed (%s): treating it as unplugged", port.path, e)
            self._apply("unplug", 1.0)
            return
        if not chunk:
            return
        self._last = time.perf_counter()
        buf = self._buf
        buf += chunk
        if self.bus.trace:
            log.info("rx %s", chunk.hex(" "))
        while len(buf) >= 2:
            n = _native.rtu_request_length(bytes(buf))
            if n < 0 or len(buf) < n:
                if n != _INCOMPLETE and len(buf) > _MAX_BUFFER:
                    self.bus.stats.bad_frames += 1
                    buf.clear()
                return  # more bytes to come, or only silence can end it
            frame = bytes(buf[:n])
            del buf[:n]
            self._dispatch(frame)
            if self._port is not port:
                return  # unplugged by a fault

    def _on_silence(self) -> None:
        """3.5 characters of silence: whatever is buffered is one frame."""
        frame = bytes(self._buf)
        self._buf.clear()
        if len(frame) >= 4 and _native.rtu_crc_ok(frame):
            self._dispatch(frame)
        else:
            self.bus.stats.bad_frames += 1

    def _dispatch(self, frame: bytes) -> None:
        t0 = time.perf_counter_ns()
        end = self._last
        if not _native.rtu_crc_ok(frame):
            self.bus.stats.bad_frames += 1
            return
        port = self._port
        assert port is not None
        line = port.line_baud()
        self._line_baud = line
        address = frame[0]
        out = self.bus.serve(address, frame[1:-2], line_baud=line)
        if out is None:
            return
        fault = out.fault
        if out.pdu is None:
            if fault is not None and fault.kind == "unplug":
                self._apply("unplug", fault.seconds)
            return
        reply = frame_rtu(address, out.pdu, fault)
        self.bus.stats.served(time.perf_counter_ns() - t0)
        if self.emulate and line is not None:
            char = char_time(line)
            start = end + len(frame) * char + max(reply_gap(line), out.delay)
        else:
            char = 0.0
            start = end + out.delay
        self._send(reply, start, char)

    def _send(self, data: bytes, start: float, char: float) -> None:
        """Write ``data`` so that it reaches the master as a line would
        deliver it: all at ``start``, or paced at ``char`` seconds a byte."""
        if self.bus.trace:
            log.info("tx %s", data.hex(" "))
        if char <= 0.0:
            if sleep_until(start, self._stop):
                self._write(data)
            return
        step = max(1, int(0.002 / char))  # bytes written together, about 2 ms of line
        for i in range(0, len(data), step):
            part = data[i:i + step]
            if not sleep_until(start + (i + len(part)) * char, self._stop):
                return
            self._write(part)

    def _write(self, data: bytes) -> None:
        port = self._port
        if port is not None:
            write_all(port.fd, data, _WRITE_WAIT_S)
