"""What every simulated device shares: the :class:`Device` base (a pure
function of request PDUs, with its lock and register images), the Modbus
exception codes and replies, the deterministic noise the value models draw
on, the encodings (sign-magnitude, firmware versions) and the keys every
device spec takes (:data:`SIM_KEYS`).

A device takes a request PDU (function code first) and returns the reply PDU,
or ``None`` for silence; it does no I/O and knows nothing of framing or
timing, which the bus adds (:mod:`pymb.sim.bus`). State lives in
``array('H')`` register images, so a read is one slice, one ``byteswap`` and
one ``tobytes``. Values are a deterministic function of the device's seed and
the simulated time of its :class:`~pymb.sim.clock.SimClock`: freeze or step
the clock and the values follow. Test hooks (pin a raw value, force a channel
offline, raise a status bit, change the firmware) take effect at once.
"""

from __future__ import annotations

import abc
import functools
import math
import random
import sys
import threading
from collections.abc import Callable, Mapping, Sequence
from typing import ClassVar, Concatenate, ParamSpec, TypeVar

from pymb._native import DeviceExceptionCode as ExceptionCode
from pymb._native import FunctionCode
from pymb.errors import InvalidArgument
from pymb.sim.clock import SimClock

__all__ = [
    "SIM_KEYS",
    "Device",
    "ExceptionCode",
    "Function",
    "exception_pdu",
    "parse_firmware",
    "seconds",
    "sign_magnitude",
]

_SWAP = sys.byteorder == "little"  # registers go on the wire big-endian
_M64 = 0xFFFF_FFFF_FFFF_FFFF
_TWO_PI = 2.0 * math.pi


#: Modbus function codes ([MB-AP] 6): the compiler's, from libmodbus's modbus.h.
Function = FunctionCode


def exception_pdu(function: int, code: int) -> bytes:
    """The exception reply to ``function``: function | 0x80, then ``code``."""
    return bytes(((function | 0x80) & 0xFF, code & 0xFF))


def _mix(x: int) -> int:
    """splitmix64's finaliser: a fast, well-spread 64-bit hash step."""
    x = (x + 0x9E3779B97F4A7C15) & _M64
    x = ((x ^ (x >> 30)) * 0xBF58476D1CE4E5B9) & _M64
    x = ((x ^ (x >> 27)) * 0x94D049BB133111EB) & _M64
    return x ^ (x >> 31)


def _noise(*keys: int) -> float:
    """A number in [0, 1) that depends only on ``keys`` (seed, channel, tick, salt)."""
    h = 0
    for k in keys:
        h = _mix(h ^ (k & _M64))
    return h / 18446744073709551616.0


def episode(key: int, salt: int, window: int, window_s: float, probability: float,
            longest_s: float) -> tuple[float, float] | None:
    """The one episode (start, end) that window number ``window`` of
    ``window_s`` seconds has with ``probability`` (None: none), 5 s to
    ``longest_s`` long, somewhere in it; drawn from ``key`` with salts
    ``salt`` to ``salt + 2``."""
    if _noise(key, salt, window) >= probability:
        return None
    length = 5.0 + (longest_s - 5.0) * _noise(key, salt + 1, window)
    start = window * window_s + (window_s - length) * _noise(key, salt + 2, window)
    return start, start + length


def sign_magnitude(tenths: int) -> int:
    """Encode tenths of a degree as [HUB] 3 does: bit 15 sign, bits 14..0
    magnitude. The magnitude is capped so the result is never 0xFFFF."""
    if tenths < 0:
        return 0x8000 | min(-tenths, 0x7FFE)
    return min(tenths, 0x7FFE)


def parse_firmware(version: str | Sequence[int]) -> tuple[int, ...]:
    """``"2.19"``, ``"V2.19"`` or ``(2, 19)`` as a tuple of ints, for comparing."""
    if isinstance(version, str):
        text = version.strip().lstrip("vV")
        try:
            parts = tuple(int(p) for p in text.split("."))
        except ValueError:
            parts = ()
        if not parts:
            raise InvalidArgument(f"firmware version must look like 2.19, got {version!r}")
        return parts
    return tuple(int(p) for p in version)


_D = TypeVar("_D", bound="Device")
_P = ParamSpec("_P")
_R = TypeVar("_R")


def _locked(method: Callable[Concatenate[_D, _P], _R]) -> Callable[Concatenate[_D, _P], _R]:
    """Run ``method`` holding the device's lock (the bus thread and a test
    thread may both touch a device)."""

    @functools.wraps(method)
    def wrapper(self: _D, /, *args: _P.args, **kwargs: _P.kwargs) -> _R:
        with self.lock:
            return method(self, *args, **kwargs)

    return wrapper


#: spec keys -> (constructor argument, parser, what the value is)
Keys = Mapping[str, tuple[str, Callable[[str], object], str]]


def _flag(value: str) -> bool:
    return {"1": True, "true": True, "yes": True, "on": True, "0": False, "false": False,
            "no": False, "off": False}[value.lower()]


#: the longest wait before a reply a simulated device takes, in seconds
MAX_DELAY_S = 60.0


def seconds(value: str) -> float:
    """A wait before a reply: 0..:data:`MAX_DELAY_S` seconds (ValueError else)."""
    s = float(value)
    if not 0.0 <= s <= MAX_DELAY_S:  # NaN too
        raise ValueError(value)
    return s


def _delay(value: str) -> float | tuple[float, float]:
    lo, sep, hi = value.partition("-")
    if not sep:
        return seconds(value)
    low, high = seconds(lo), seconds(hi)
    if low > high:
        raise ValueError(value)
    return (low, high)


def _baud(value: str) -> int:
    if int(value) <= 0:
        raise ValueError(value)
    return int(value)


#: the simulator's own keys of every device spec, beside its map's options
SIM_KEYS: Keys = {
    "firmware": ("firmware", str, "a version: points need their min_firmware"),
    "delay": ("delay", _delay, f"0..{MAX_DELAY_S:g} seconds before each reply, or LOW-HIGH"),
    "baud": ("baud", _baud, "a number of bit/s"),
    "dynamic": ("dynamic", _flag, "0 or 1: values move"),
}


class Device(abc.ABC):
    """What the bus needs of a simulated device.

    ``address`` and ``baud`` are the ones it answers at *now* (a CoolPro
    changes them only at a reset). ``handle`` returns the reply PDU or None.
    """

    kind: ClassVar[str] = ""
    #: exception code the ``busy`` fault answers with: 04, the CoolPro's "Slave
    #: Device Failure" ([CP] ch. 05), the hub's "busy" ([HUB] 2.3.2.3)
    busy_code: ClassVar[int] = ExceptionCode.SLAVE_OR_SERVER_FAILURE

    def __init__(self, address: int, *, baud: int, seed: int, clock: SimClock | None) -> None:
        self.seed = int(seed)
        self.clock = clock if clock is not None else SimClock()
        self._address = address
        self._baud = baud
        self.rng = random.Random(_mix(self.seed ^ 0x5EED))  # turnaround jitter, faults
        #: held by the bus around :meth:`handle` and by every public setter
        self.lock = threading.RLock()

    @property
    def address(self) -> int:
        """The slave address the device answers at."""
        return self._address

    @property
    def baud(self) -> int:
        """The line speed the device listens at (8N1)."""
        return self._baud

    def turnaround(self) -> float:
        """Seconds from the end of a request to the start of the reply."""
        return 0.0

    @abc.abstractmethod
    def handle(self, pdu: bytes) -> bytes | None:
        """The reply PDU to request ``pdu`` addressed to this device."""

    def handle_broadcast(self, pdu: bytes) -> None:  # noqa: B027 (a no-op by default)
        """A request sent to address 0: never answered."""

    def idle(self) -> None:  # noqa: B027 (a no-op by default)
        """The line is quiet: a chance to bring values up to date off the
        request path."""

    def sensor_fault(self, rng: random.Random, seconds: float, *, bits: int | None = None,
                     channels: Sequence[int] | None = None) -> str:
        """Raise a sensor fault for ``seconds``; returns what it did. A device
        without sensors (the default) does nothing and says so: a subclass
        that only answers requests needs only :meth:`handle`."""
        del rng, seconds, bits, channels
        return "no sensors to fault"

    def describe(self) -> str:
        """One line for the command line's banner."""
        return f"{self.kind} at address {self.address} ({self.baud} 8N1)"

    def __repr__(self) -> str:
        return f"<{type(self).__name__} address={self.address} baud={self.baud}>"
