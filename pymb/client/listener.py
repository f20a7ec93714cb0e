"""Listening to a whole RTU line: requests sent raw on an open client's
descriptor, and every frame that comes back, to whichever address, taken
apart by the C core. ``pymb scan`` asks many addresses at once through it."""

from __future__ import annotations

import math
import os
import select
import time

from pymb import _native
from pymb.errors import ModbusConnectionError
from pymb.wire import GAP_CHARS, char_time

__all__ = ["QUIET_S", "LineListener"]

QUIET_S = 0.02  #: a partial frame with no byte for this long is noise


class LineListener:
    """Sends RTU requests on an open serial line and reads every frame that
    comes back, crediting each to the address it names (an RTU reply carries
    its sender's address, so a reply that comes late, while later addresses
    are asked, is still credited to its sender). The receive loop of a scan:
    frames are ended by the line's silence and checked by the C core (length,
    CRC)."""

    def __init__(self, fd: int, baudrate: int, bits: int) -> None:
        self.fd = fd
        self.char = char_time(baudrate, bits)
        self.buf = bytearray()
        self.last_byte = 0.0
        self.heard: list[int] = []  #: addresses heard from, in order, not yet taken
        self.garbled = 0  #: bytes dropped as noise

    def send(self, address: int, function: int, data: bytes) -> float:
        """Send a request; returns when its last bit will have left."""
        frame = _native.with_crc(bytes((address, function)) + data)
        view = memoryview(frame)
        while view:
            if self._ready(select.POLLOUT, 0.05):
                try:
                    view = view[os.write(self.fd, view):]
                except BlockingIOError:
                    continue
                except OSError as e:
                    raise self._lost(e) from None
        return time.monotonic() + len(frame) * self.char

    def _ready(self, events: int, seconds: float) -> bool:
        """Whether the line is ready for ``events`` within ``seconds``: poll,
        which takes any descriptor number (select() fails above 1023)."""
        p = select.poll()
        p.register(self.fd, events)
        return bool(p.poll(max(1, math.ceil(seconds * 1000))))

    def _lost(self, e: OSError) -> ModbusConnectionError:
        return ModbusConnectionError(f"the line failed during the scan: {e.strerror}",
                                     errno=e.errno)

    def listen(self, until: float, address: int | None = None,
               function: int | None = None) -> bytes | None:
        """Read until ``until``; returns the first frame from ``address`` that
        answers ``function`` (None: just listen). Every other frame is noted
        in :attr:`heard`."""
        while True:
            frame = self._take(address, function)
            if frame is not None:
                return frame
            left = until - time.monotonic()
            if left <= 0:
                return None
            if self._ready(select.POLLIN, min(left, 0.05)):
                try:
                    chunk = os.read(self.fd, 512)
                except BlockingIOError:
                    continue
                except OSError as e:
                    raise self._lost(e) from None
                if chunk:
                    self.buf += chunk
                    self.last_byte = time.monotonic()

    def _take(self, address: int | None, function: int | None) -> bytes | None:
        while len(self.buf) >= 2:
            n = _native.rtu_response_length(self.buf)
            if n == -1 or (n > 0 and len(self.buf) < n):
                if time.monotonic() - self.last_byte < QUIET_S + GAP_CHARS * self.char:
                    return None  # more may come
                self._drop()  # a partial frame followed by silence: noise
                continue
            if n < 0 or not _native.rtu_crc_ok(self.buf[:n]):
                self._drop()
                continue
            frame = bytes(self.buf[:n])
            del self.buf[:n]
            fc = frame[1] & 0x7F
            if frame[0] == address and fc == function:
                return frame
            if frame[0] and frame[0] not in self.heard:
                self.heard.append(frame[0])
        return None

    def _drop(self) -> None:
        del self.buf[:1]
        self.garbled += 1
