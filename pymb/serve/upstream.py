"""The one line behind ``pymb serve``: a thread that owns the client and sends
the clients' requests one transaction at a time, in the order they came."""

from __future__ import annotations

import errno
import queue
import threading
from collections.abc import Callable
from typing import Protocol

from pymb.errors import (
    DeviceException,
    InvalidArgument,
    ModbusConnectionError,
    ModbusError,
    ModbusTimeout,
)

__all__ = ["EX_PATH", "EX_TARGET", "Upstream", "reads_only"]

EX_PATH = 0x0A  #: gateway path unavailable: the line cannot be reached
EX_TARGET = 0x0B  #: gateway target device failed to respond

#: the public function codes that only read ([MB-AP] 6.1-6.4, 6.7, 6.9, 6.10,
#: 6.13, 6.14, 6.18); with :data:`READ_DIAGNOSTICS` and 2B/0E (read device
#: identification, 6.21), what :func:`reads_only` takes
READ_FUNCTIONS = frozenset({0x01, 0x02, 0x03, 0x04, 0x07, 0x0B, 0x0C, 0x11, 0x14, 0x18})
#: the diagnostics (08) sub-functions that only return data ([MB-AP] 6.8: 00
#: the query data, 02 the diagnostic register, 0B..12 the counters); the
#: others restart the device, clear its counters or put it in listen-only mode
READ_DIAGNOSTICS = frozenset({0x00, 0x02, *range(0x0B, 0x13)})
#: what a connection the peer closed (or reset) fails with
_CLOSED_BY_PEER = frozenset((errno.EPIPE, errno.ECONNRESET))


def reads_only(pdu: bytes) -> bool:
    """Whether request ``pdu`` (a checked PDU) only reads. Such a request may
    be sent again on a new connection when the device closed the one that
    carried it after a reply (some Modbus TCP devices and gateways take one
    request a connection), as pymb's clients send a read again; and it is
    all a TLS client whose role may not write may send. Anything else, a
    write, a diagnostic that changes the device, a user-defined or unknown
    function code, may have been done by the device, and is a write to the
    roles."""
    function = pdu[0]
    if function == 0x08:
        return len(pdu) >= 3 and int.from_bytes(pdu[1:3], "big") in READ_DIAGNOSTICS
    return function in READ_FUNCTIONS or pdu[:2] == b"\x2b\x0e"


#: what a finished transaction hands back: the reply PDU
Done = Callable[[bytes], None]
#: whether a queued request is still wanted when its turn comes (its client
#: is still connected); None: always
Wanted = Callable[[], bool] | None


class _Line(Protocol):
    def connect(self) -> None: ...
    def close(self) -> None: ...
    def raw_request(self, function: int, data: bytes = b"", *, slave: int | None = None,
                    response_length: int | None = None) -> bytes: ...


class Upstream:
    """Sends requests on ``line`` (a :class:`pymb.Client`, not yet open) from
    one thread. :meth:`submit` is called from any thread; ``done`` gets the
    reply PDU (the device's reply, its exception, or the gateway's exception
    0x0A when the line is down and 0x0B when the device did not answer) on the
    upstream's thread. At most ``depth`` requests wait: more are answered
    0x0B at once (the line cannot serve them within anyone's timeout)."""

    def __init__(self, line: _Line, *, depth: int = 1024,
                 on_event: Callable[[str], None] | None = None) -> None:
        self.line = line
        self.depth = depth
        self._jobs: queue.Queue[tuple[int, bytes, Done, Wanted] | None] = queue.Queue()
        self._on_event = on_event or (lambda _text: None)
        self._thread = threading.Thread(target=self._run, name="pymb-serve-upstream", daemon=True)
        self._connected = False
        self._down_said = False
        self._served = 0  # replies on the connection open now
        #: transactions sent, and how each ended
        self.sent = self.timeouts = self.exceptions = self.unreachable = 0
        self.dropped = 0  #: requests queued or under way when it stopped: never answered
        self.unwanted = 0  #: requests whose client had gone before their turn: never sent
        #: its thread was still in a transaction when it stopped (see :meth:`stop`)
        self.abandoned = False

    def start(self) -> None:
        """Start the upstream's thread."""
        self._thread.start()

    def stop(self, timeout: float = 0.5) -> None:
        """Drop the queued requests (their clients are gone with the server)
        and wait at most ``timeout`` seconds for the transaction under way,
        then the line's close. A transaction still waiting on a silent device
        (its reply timeout may be long) is abandoned: the thread is a daemon
        and closes the line when the transaction ends, or the process's exit
        does."""
        while True:
            try:
                if self._jobs.get_nowait() is not None:
                    self.dropped += 1
            except queue.Empty:
                break
        self._jobs.put(None)
        self._thread.join(timeout)
        if self._thread.is_alive():  # a transaction under way, abandoned
            self.dropped += 1
            self.abandoned = True

    def submit(self, unit: int, pdu: bytes, done: Done, wanted: Wanted = None) -> None:
        """Queue request ``pdu`` for ``unit``; when its turn comes, it is not
        sent if ``wanted()`` says its client has gone (counted in
        :attr:`unwanted`)."""
        if self._jobs.qsize() >= self.depth:
            done(bytes((pdu[0] | 0x80, EX_TARGET)))
            return
        self._jobs.put((unit, pdu, done, wanted))

    def _run(self) -> None:
        try:
            while True:
                job = self._jobs.get()
                if job is None:
                    return
                unit, pdu, done, wanted = job
                if wanted is not None and not wanted():
                    self.unwanted += 1
                    continue
                done(self._transact(unit, pdu))
        finally:
            self.line.close()

    def _transact(self, unit: int, pdu: bytes) -> bytes:
        function = pdu[0]
        while True:
            if not self._connected:
                try:
                    self.line.connect()
                except ModbusError as e:
                    self.unreachable += 1
                    if not self._down_said:
                        self._down_said = True
                        self._on_event(f"upstream unreachable: {e} (answering 0x0A)")
                    return bytes((function | 0x80, EX_PATH))
                if self._down_said:
                    self._on_event("upstream reachable again")
                self._connected, self._down_said, self._served = True, False, 0
            self.sent += 1
            try:
                reply = bytes((function,)) + self.line.raw_request(function, pdu[1:], slave=unit)
            except DeviceException as e:
                self.exceptions += 1
                self._served += 1
                return bytes((function | 0x80, e.code & 0xFF))
            except ModbusTimeout:
                self.timeouts += 1
                return bytes((function | 0x80, EX_TARGET))
            except ModbusConnectionError as e:
                self._connected = False
                self.line.close()
                if self._served and e.errno in _CLOSED_BY_PEER and reads_only(pdu):
                    continue  # closed after its last reply: the read again, on a new one
                self.unreachable += 1
                self._on_event(f"upstream connection lost: {e}")
                return bytes((function | 0x80, EX_PATH))
            except (ModbusError, InvalidArgument):  # a reply that was not one: no answer
                self.timeouts += 1
                return bytes((function | 0x80, EX_TARGET))
            self._served += 1
            return reply
