"""The bus: devices sharing one line, routing, faults, line timing.

Transport-neutral: :meth:`Bus.serve` takes a slave address and a request
PDU and returns a :class:`BusReply` (the reply PDU, how long the device
takes, which fault applies) or None for silence. The RTU and TCP servers add
framing, the wire's timing and the faults that live in the framing.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from typing import NamedTuple

from pymb import _native
from pymb.sim.devices import Device, exception_pdu
from pymb.sim.faults import Fault, Faults
from pymb.wire import GAP_CHARS, char_time

__all__ = ["IDLE_S", "Bus", "BusReply", "BusStats", "char_time", "silence", "sleep_until"]

log = logging.getLogger("pymb.sim")

_FAST = 38400  #: a rate above 19200 bit/s, where the silence is the fixed floor

#: a quiet line lets the devices update their values this often (off the request path)
IDLE_S = 0.25


def silence(baud: int | None, bits: int = 10) -> float:
    """The 3.5-character silence that ends an RTU frame ([MB-SL] 2.5.1.1);
    1.75 ms at any rate above 19200. None (speed unknown): 1.75 ms."""
    if baud is None or baud > 19200:
        return _native.rtu_silence(_FAST)  # the C core's floor: one home for it
    return GAP_CHARS * char_time(baud, bits)


def reply_gap(baud: int, bits: int = 10) -> float:
    """The line model's gap between a request's last byte and the reply's
    first: exactly 3.5 characters at any speed (the theoretical wire time
    pymb's planner and benchmark count: :mod:`pymb.wire`). The 1.75 ms of
    :func:`silence` is a receiver's frame-end timer above 19200 bit/s, not a
    delay a device owes."""
    return GAP_CHARS * char_time(baud, bits)


def sleep_until(deadline: float, stop: threading.Event | None = None) -> bool:
    """Sleep until ``time.perf_counter()`` reaches ``deadline``: the OS
    sleeps most of it, the last 0.2 ms is spun for precision. Returns False
    when ``stop`` was set meanwhile."""
    while True:
        left = deadline - time.perf_counter()
        if left <= 0:
            return not (stop is not None and stop.is_set())
        if left > 0.0002:
            if stop is not None:
                if stop.wait(left - 0.0002):
                    return False
            else:
                time.sleep(left - 0.0002)


class BusReply(NamedTuple):
    """What the bus does with one request."""

    device: Device
    pdu: bytes | None  #: the reply PDU; None: no reply
    delay: float  #: seconds from the request's end to the reply's start
    fault: Fault | None  #: the fault applied, if any


@dataclass
class BusStats:
    """Counters of one bus; ``service_ns`` is the simulator's own time per
    answered request (request complete to reply framed, no intended delays)."""

    requests: int = 0  #: frames with a good CRC (or TCP requests)
    replies: int = 0
    broadcasts: int = 0
    ignored: int = 0  #: no device at that address, or at another line speed
    bad_frames: int = 0  #: bad CRC, garbage, too short
    service_ns_total: int = 0
    service_ns_max: int = 0

    def served(self, ns: int) -> None:
        """Record one reply and the time it took to make."""
        self.replies += 1
        self.service_ns_total += ns
        if ns > self.service_ns_max:
            self.service_ns_max = ns

    @property
    def service_ns_mean(self) -> float:
        """Mean service time of the replies so far, in nanoseconds."""
        return self.service_ns_total / self.replies if self.replies else 0.0


class Bus:
    """Devices on one line; routes each request to the one it addresses.

    ``check_line``: a device ignores frames sent at another speed than its
    own, as a real one hears only garbage then (the RTU server passes the
    speed the master set on the line).
    """

    def __init__(self, devices: list[Device], faults: Faults, *, check_line: bool = True,
                 trace: bool = False) -> None:
        self.devices = tuple(devices)
        self.faults = faults
        self.check_line = check_line
        self.trace = trace
        self.stats = BusStats()
        self._warned: set[tuple[int, int, int]] = set()

    def idle(self) -> None:
        """Called when the line has been quiet for a while."""
        for d in self.devices:
            d.idle()

    def device(self, address: int) -> Device | None:
        """The device answering at ``address`` now, or None."""
        for d in self.devices:
            if d.address == address:
                return d
        return None

    def serve(self, address: int, pdu: bytes, *, line_baud: int | None = None,
              tcp: bool = False) -> BusReply | None:
        """Route one request; None when no device answers it."""
        self.stats.requests += 1
        if address == 0:
            self.stats.broadcasts += 1
            for d in self.devices:
                with d.lock:
                    d.handle_broadcast(pdu)
            return None
        dev = self.device(address)
        if dev is None:
            self.stats.ignored += 1
            return None
        if self.check_line and line_baud is not None and line_baud != dev.baud:
            self._mismatch(dev, line_baud)
            self.stats.ignored += 1
            return None
        fault = self.faults.pick(address, pdu[0], tcp=tcp) if pdu else None
        if fault is not None:
            kind = fault.kind
            if self.trace:
                log.info("fault %s on request to %d", kind, address)
            if kind == "sensor":
                what = dev.sensor_fault(self.faults.rng, fault.seconds, bits=fault.bits,
                                        channels=fault.channels)
                log.info("sensor fault on %s: %s", dev.kind, what)
                fault = None
            elif kind in ("exception", "busy"):
                code = fault.code if kind == "exception" else dev.busy_code
                return BusReply(dev, exception_pdu(pdu[0], code), dev.turnaround(), fault)
            elif kind in ("no_reply", "unplug"):
                return BusReply(dev, None, 0.0, fault)
        with dev.lock:
            reply = dev.handle(pdu)
        delay = dev.turnaround()
        if fault is not None and fault.kind == "late":
            delay += fault.delay
        return BusReply(dev, reply, delay, fault)

    def _mismatch(self, dev: Device, line_baud: int) -> None:
        key = (id(dev), dev.baud, line_baud)
        if key not in self._warned:
            self._warned.add(key)
            log.warning(
                "%s at address %d listens at %d baud but the master sends at %d: "
                "it hears only garbage and stays silent, as a real one would",
                dev.kind, dev.address, dev.baud, line_baud)
