"""Fault injection: what goes wrong, when, and how often it did.

A :class:`Faults` plan is consulted once per request that a device on the bus
would answer (right address, good CRC, right line speed). It returns at most
one :class:`Fault`, from the scripted queue first (:meth:`Faults.inject`:
"the next N matching requests"), else by probability (:meth:`Faults.set_rate`)
from a seeded generator, so a run is reproducible. :attr:`Faults.counts`
says how many of each kind were applied.

Kinds:

``no_reply``       the device stays silent
``late``           the reply comes ``delay`` seconds late (default 1 s)
``bad_crc``        the reply's CRC is wrong (RTU only)
``truncate``       only the first ``keep`` bytes are sent (default: half)
``stray``          ``extra`` bytes follow a valid reply (default 3 seeded bytes)
``wrong_address``  a valid reply from address ``to`` (default: the next address)
``exception``      exception ``code`` (default 04) instead of the answer
``busy``           the device's busy exception (the hub's 04; the CoolPro's
                   closest, 04 Slave Device Failure)
``sensor``         a sensor fault for ``seconds``: CoolPro status ``bits``
                   (default: one measurement fault), hub ``channels`` offline
                   (default: one); the request is then answered
``unplug``         the port disappears for ``seconds`` (default 1 s)
"""

from __future__ import annotations

import math
import random
import threading
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

from pymb.errors import InvalidArgument

__all__ = ["KINDS", "RTU_ONLY", "Fault", "Faults", "framed", "parse_fault"]

KINDS = ("no_reply", "late", "bad_crc", "truncate", "stray", "wrong_address", "exception",
         "busy", "sensor", "unplug")
#: kinds that need RTU framing (a TCP reply has no CRC)
RTU_ONLY = frozenset({"bad_crc"})


@dataclass(frozen=True)
class Fault:
    """One fault and its parameters (see the module's table)."""

    kind: str
    delay: float = 1.0  #: late: seconds added
    code: int = 0x04  #: exception: the code
    keep: int | None = None  #: truncate: bytes sent (default half the reply)
    extra: bytes | None = None  #: stray: bytes after the reply
    to: int | None = None  #: wrong_address: the address the reply carries
    seconds: float = 1.0  #: sensor, unplug: how long
    bits: int | None = None  #: sensor (CoolPro): status bits
    channels: tuple[int, ...] | None = None  #: sensor (hub): channels

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise InvalidArgument(f"unknown fault {self.kind!r}; use one of {', '.join(KINDS)}")
        for key in ("delay", "seconds"):
            value = getattr(self, key)
            if not 0 <= value < math.inf:  # NaN too
                raise InvalidArgument(f"{key} must be 0 or more seconds, got {value!r}")
        if not 1 <= self.code <= 255:
            raise InvalidArgument(f"exception code must be 1..255, got {self.code!r}")
        if self.keep is not None and self.keep < 0:
            raise InvalidArgument(f"truncate keep must be 0 or more bytes, got {self.keep!r}")
        if self.to is not None and not 0 <= self.to <= 255:
            raise InvalidArgument(f"wrong_address to must be 0..255, got {self.to!r}")


@dataclass
class _Rule:
    fault: Fault
    address: int | None
    function: int | None
    count: int = 0  # scripted: requests left
    probability: float = 0.0  # by rate

    def matches(self, address: int, function: int) -> bool:
        return (self.address is None or self.address == address) and (
            self.function is None or self.function == function)


@dataclass
class Faults:
    """The fault plan of one simulator; thread-safe (the bus thread picks
    while a test injects)."""

    seed: int = 0
    _rng: random.Random = field(init=False, repr=False)
    _lock: threading.Lock = field(init=False, repr=False, default_factory=threading.Lock)
    _script: list[_Rule] = field(init=False, default_factory=list)
    _rates: list[_Rule] = field(init=False, default_factory=list)
    _counts: Counter[str] = field(init=False, default_factory=Counter)

    def __post_init__(self) -> None:
        self._rng = random.Random(self.seed)

    @property
    def rng(self) -> random.Random:
        """The seeded generator faults draw from (also their random parameters)."""
        return self._rng

    def inject(self, kind: str, count: int = 1, *, address: int | None = None,
               function: int | None = None, **params: object) -> None:
        """Apply fault ``kind`` to the next ``count`` requests (to ``address``
        and of ``function`` when given). Parameters as in :class:`Fault`."""
        if count < 1:
            raise InvalidArgument(f"count must be 1 or more, got {count!r}")
        rule = _Rule(_make(kind, params), address, function, count=count)
        with self._lock:
            self._script.append(rule)

    def set_rate(self, kind: str, probability: float, *, address: int | None = None,
                 function: int | None = None, **params: object) -> None:
        """Apply fault ``kind`` to each matching request with ``probability``
        (0 removes the rate). Replaces an earlier rate of the same kind and filter."""
        if not 0.0 <= probability <= 1.0:
            raise InvalidArgument(f"probability must be 0..1, got {probability!r}")
        fault = _make(kind, params)
        with self._lock:
            self._rates = [r for r in self._rates if not (
                r.fault.kind == kind and r.address == address and r.function == function)]
            if probability > 0:
                self._rates.append(_Rule(fault, address, function, probability=probability))

    def add(self, spec: str) -> None:
        """Add a rate from the command line's ``KIND[:PROBABILITY][,key=value...]``."""
        fault, probability, address = parse_fault(spec)
        with self._lock:
            self._rates.append(_Rule(fault, address, None, probability=probability))

    def clear(self) -> None:
        """Remove every scripted fault and rate (the counts stay)."""
        with self._lock:
            self._script.clear()
            self._rates.clear()

    @property
    def pending(self) -> int:
        """Scripted faults not yet applied."""
        with self._lock:
            return sum(r.count for r in self._script)

    @property
    def counts(self) -> dict[str, int]:
        """Faults applied so far, per kind (every kind listed)."""
        with self._lock:
            return {k: self._counts[k] for k in KINDS}

    def reset_counts(self) -> None:
        """Set every count back to 0."""
        with self._lock:
            self._counts.clear()

    def pick(self, address: int, function: int, *, tcp: bool = False) -> Fault | None:
        """The fault for one request, counted as applied; None for none."""
        with self._lock:
            for rule in self._script:
                if rule.matches(address, function) and not (tcp and rule.fault.kind in RTU_ONLY):
                    rule.count -= 1
                    if rule.count == 0:
                        self._script.remove(rule)
                    return self._applied(rule.fault)
            for rule in self._rates:
                if rule.matches(address, function) and not (
                        tcp and rule.fault.kind in RTU_ONLY) and \
                        self._rng.random() < rule.probability:
                    return self._applied(rule.fault)
        return None

    def _applied(self, fault: Fault) -> Fault:
        self._counts[fault.kind] += 1
        if fault.kind == "stray" and fault.extra is None:
            fault = replace(fault, extra=bytes(self._rng.randrange(256) for _ in range(3)))
        return fault


def framed(frame: Callable[[int], bytes], address: int, fault: Fault | None) -> bytes:
    """The reply ``frame(address)`` (its framing's bytes, from the device at
    ``address``) with the framing faults applied: ``wrong_address`` frames it
    from another address; ``bad_crc`` spoils its last two bytes (RTU's CRC:
    never picked for TCP); ``truncate`` and ``stray`` cut it short or add
    bytes after it. The one rule of the faults in a framing, RTU's and TCP's."""
    if fault is not None and fault.kind == "wrong_address":
        address = fault.to if fault.to is not None else address % 247 + 1
    adu = frame(address)
    if fault is None:
        return adu
    kind = fault.kind
    if kind == "bad_crc":
        return adu[:-2] + bytes((adu[-2] ^ 0xFF, adu[-1] ^ 0x5A))
    if kind == "truncate":
        keep = fault.keep if fault.keep is not None else len(adu) // 2
        return adu[:min(keep, len(adu) - 1)]
    if kind == "stray":
        return adu + (fault.extra or b"\x00")
    return adu


def _make(kind: str, params: dict[str, object]) -> Fault:
    if kind not in KINDS:
        raise InvalidArgument(f"unknown fault {kind!r}; use one of {', '.join(KINDS)}")
    known = set(Fault.__dataclass_fields__) - {"kind"}
    bad = set(params) - known
    if bad:
        raise InvalidArgument(f"{kind}: unknown parameters {sorted(bad)}; use {sorted(known)}")
    p = dict(params)
    if isinstance(p.get("channels"), int):
        p["channels"] = (p["channels"],)
    elif isinstance(p.get("channels"), Sequence):
        p["channels"] = tuple(p["channels"])  # type: ignore[arg-type]
    if kind == "busy" and "code" in p:
        raise InvalidArgument("busy takes no code: use exception with code=N")
    return Fault(kind, **p)  # type: ignore[arg-type]


_PARAM_TYPES = {"delay": float, "seconds": float, "code": int, "keep": int, "to": int,
                "bits": int, "address": int}


def parse_fault(spec: str) -> tuple[Fault, float, int | None]:
    """``KIND[:PROBABILITY][,key=value...]`` as (fault, probability, address).

    The probability defaults to 1 (every request). Keys: ``delay``,
    ``seconds``, ``code``, ``keep``, ``to``, ``bits``, ``channels`` (``3+4``),
    ``extra`` (hex), ``address`` (only requests to that address).
    Example: ``late:0.1,delay=1.5``.
    """
    head, *opts = spec.split(",")
    kind, _, prob = head.partition(":")
    try:
        probability = float(prob) if prob else 1.0
    except ValueError:
        raise InvalidArgument(f"fault {spec!r}: probability {prob!r} is not a number") from None
    if not 0.0 <= probability <= 1.0:
        raise InvalidArgument(f"fault {spec!r}: probability must be 0..1")
    params: dict[str, object] = {}
    address = None
    for opt in opts:
        key, eq, value = opt.partition("=")
        if not eq:
            raise InvalidArgument(f"fault {spec!r}: {opt!r} is not key=value")
        keys = ["channels", "extra", *_PARAM_TYPES]
        if key not in keys:
            raise InvalidArgument(f"fault {spec!r}: unknown key {key!r}; use "
                                  f"{', '.join(k + '=...' for k in keys)}")
        try:
            if key == "channels":
                params[key] = tuple(int(c) for c in value.split("+"))
            elif key == "extra":
                params[key] = bytes.fromhex(value)
            else:
                v = _PARAM_TYPES[key](value, 0) if _PARAM_TYPES[key] is int else float(value)
                if key == "address":
                    address = int(v)
                else:
                    params[key] = v
        except ValueError:
            raise InvalidArgument(f"fault {spec!r}: bad value for {key}: {value!r}") from None
    try:
        return _make(kind.strip(), params), probability, address
    except InvalidArgument as e:
        raise InvalidArgument(f"fault {spec!r}: {e}") from None
