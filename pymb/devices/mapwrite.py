"""Writing points of a map device, safely (the ``pymb.write/1`` contract).

Every write, whatever asks for it, goes the same way:

1. **check** every value before anything is sent (:func:`check`): the point
   exists (a wrong name gets the closest known one), is writable, the value
   fits its type, ``valid`` and ``values``; a command of several values is
   checked whole, and one refusal writes nothing;
2. **policy**: the point's write budget (``max_writes_per_hour``) is not
   spent (:class:`WriteBudget`); a refusal sends nothing, not even a read;
3. **send** with the fewest requests that keep every point whole
   (:func:`requests`): FC 06 for one register (FC 16 with ``write_multiple =
   "always"``), FC 16 for adjacent registers, FC 05 / FC 15 for coils; a
   ``bit``, ``bits`` or 8-bit half is read, changed and written back, or
   changed by FC 22 where ``mask_write = true``;
4. **read back** and compare registers: a point is applied only when the
   device holds what was sent.

:class:`~pymb.devices.MapDevice` runs these under its line lock, so a write
never goes between the requests of a read.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections import deque
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

from pymb.errors import InvalidArgument, ModbusError, WriteNotApplied, WriteRefused, closest_hint
from pymb.maps import Map, Point, Value
from pymb.maps.codec import decode_one, encode

__all__ = ["Budget", "Change", "Outcome", "WriteBudget", "WriteRequest", "check", "requests"]

_VIEWS = frozenset({"bit", "bits", "u8_hi", "u8_lo", "i8_hi", "i8_lo"})
_MAX_FC16 = 123  #: registers of one FC 16 request ([MB-AP] 6.12)
_MAX_FC15 = 1968  #: coils of one FC 15 request ([MB-AP] 6.11)
_HOUR = 3600.0


@dataclass(frozen=True)
class Change:
    """One checked value: ``name`` as given (a block's channel as
    ``name_N``), its point (one channel of a block as a point of its own),
    the value, and the registers (bits) it writes; for a ``bit``, ``bits``
    or 8-bit half, ``keep`` is the mask of the bits it leaves alone in each
    register and ``registers`` its bits with the others 0."""

    name: str
    point: Point
    value: object
    registers: tuple[int, ...]
    keep: tuple[int, ...] | None = None
    sf: int | None = None  #: the scale factor it was encoded with (``scale_from``)

    @property
    def view(self) -> bool:
        """A view shares its registers: read, changed and written back."""
        return self.keep is not None

    def merged(self, current: Sequence[int]) -> tuple[int, ...]:
        """The registers to write given the ``current`` ones."""
        if self.keep is None:
            return self.registers
        return tuple((c & k) | (r & ~k & 0xFFFF)
                     for c, k, r in zip(current, self.keep, self.registers, strict=True))


@dataclass(frozen=True)
class WriteRequest:
    """One write request: ``function`` (5, 6, 15, 16 or 22), ``table``,
    ``address`` and ``values`` (registers or bits; for FC 22 the AND and OR
    masks). ``rmw``: the registers come from the device's current ones
    (unknown until read); ``names``: the points it writes."""

    function: int
    table: str
    address: int
    values: tuple[int, ...]
    names: tuple[str, ...]
    rmw: bool = False

    def describe(self) -> str:
        """One line: ``FC 06 holding 10: 0x1356 (setpoint_hz)``."""
        if self.function == 22:
            data = f"and 0x{self.values[0]:04X} or 0x{self.values[1]:04X}"
        elif self.table == "coil":
            data = " ".join(str(v) for v in self.values)
        else:
            data = " ".join(f"0x{v:04X}" for v in self.values)
        if self.rmw:
            data = f"read (FC {'01' if self.table == 'coil' else '03'}), then {data} " \
                   "with the other bits as read"
        return f"FC {self.function:02d} {self.table} {self.address}: {data} " \
               f"({', '.join(self.names)})"


@dataclass
class Outcome:
    """What became of one value: ``before`` (None when not read), ``after``
    (the value read back; None when not verified), ``applied`` (the device
    holds what was sent; None when not verified) and ``sent`` (False for a
    write of the value the device already held)."""

    name: str
    requested: object
    before: Value = None
    after: Value = None
    applied: bool | None = None
    sent: bool = False


class Budget(Protocol):
    """Where writes are counted against ``max_writes_per_hour``."""

    def spent(self, key: str, limit: int) -> bool:
        """True when ``limit`` writes of ``key`` were made in the last hour."""
        ...

    def count(self, key: str) -> None:
        """Count one write of ``key``, now."""
        ...


class WriteBudget:
    """``max_writes_per_hour``: the writes of each point in the last hour,
    kept in memory (the logger keeps its own in its database). ``key``
    names the device and the point."""

    def __init__(self, clock: Callable[[], float] = time.time) -> None:
        self._clock = clock
        self._writes: dict[str, deque[float]] = {}

    def _recent(self, key: str) -> deque[float]:
        q = self._writes.setdefault(key, deque())
        cutoff = self._clock() - _HOUR
        while q and q[0] <= cutoff:
            q.popleft()
        return q

    def spent(self, key: str, limit: int) -> bool:
        """True when ``limit`` writes of ``key`` were made in the last hour."""
        return len(self._recent(key)) >= limit

    def count(self, key: str) -> None:
        """Count one write of ``key``, now."""
        self._recent(key).append(self._clock())


def _channel_point(p: Point, channel: int) -> Point:
    return dataclasses.replace(p, address=p.address_of(channel), channels=1, stride=0,
                               block=False)


def _names(m: Map) -> list[str]:
    out: list[str] = []
    for p in m.points.values():
        if p.block:
            out.extend(f"{p.name}_{c}" for c in range(1, p.channels + 1))
        else:
            out.append(p.name)
    return out


def _writable(m: Map) -> str:
    """The points a write may name, a block as its channels' range (a hub's
    600 read-only channels are no list to read through)."""
    names = sorted(f"{p.name}_1..{p.name}_{p.channels}" if p.block else p.name
                   for p in m.points.values() if p.writable)
    return f"; writable: {', '.join(names)}" if names else "; it has no writable point"


def resolve(m: Map, name: object, channel: int | None = None) -> tuple[str, Point]:
    """The point ``name`` writes (one channel of a block: ``name`` with
    ``channel``, or ``name_N``), with its label; an
    :class:`~pymb.InvalidArgument` naming the closest point otherwise."""
    if not isinstance(name, str):
        raise InvalidArgument(f"{m.id}: a point name is text, got {name!r}")
    p = m.points.get(name)
    if p is None and channel is None:
        base, _, n = name.rpartition("_")
        b = m.points.get(base)
        if b is not None and b.block and n.isdigit() and 1 <= int(n) <= b.channels:
            return name, _channel_point(b, int(n))
    if p is None:
        hint = closest_hint(name, _names(m)) or _writable(m)
        raise InvalidArgument(f"{m.id}: no point {name!r}{hint}")
    if p.block:
        if channel is None:
            raise InvalidArgument(f"{m.id}: {name!r} is a block: write one channel "
                                  f"({name}_1..{name}_{p.channels}, or channel=N)")
        if isinstance(channel, bool) or not isinstance(channel, int) or not (
                1 <= channel <= p.channels):
            raise InvalidArgument(f"{m.id}: {name!r} has channels 1..{p.channels}, "
                                  f"not {channel!r}")
        return f"{name}_{channel}", _channel_point(p, channel)
    if channel is not None:
        raise InvalidArgument(f"{m.id}: {name!r} has no channels")
    return name, p


def check(m: Map, values: Iterable[tuple[str, int | None, object]],
          scale_factors: Mapping[str, int | None] | None = None) -> list[Change]:
    """Every ``(name, channel, value)`` checked and encoded, or an
    :class:`~pymb.InvalidArgument` for the first refused (nothing sent).
    ``scale_factors``: the values of the ``scale_from`` points they need,
    by name (a point scaled by one that is missing or not implemented is
    refused)."""
    changes: list[Change] = []
    for name, channel, value in values:
        label, p = resolve(m, name, channel)
        sf = (scale_factors or {}).get(p.scale_from) if p.scale_from is not None else None
        try:
            if p.type in _VIEWS or p.mask is not None:
                low = encode(p, value, current=[0] * p.count, sf=sf)
                high = encode(p, value, current=[0xFFFF] * p.count, sf=sf)
                keep = tuple(a ^ b for a, b in zip(low, high, strict=True))
                changes.append(Change(label, p, value, tuple(low), keep, sf))
            else:
                changes.append(Change(label, p, value, tuple(encode(p, value, sf=sf)),
                                      sf=sf))
        except InvalidArgument as e:
            raise InvalidArgument(f"{m.id}: {e}") from None
        if p.table != "coil" and p.count > _MAX_FC16:
            raise InvalidArgument(f"{m.id}: point {label!r}: its {p.count} registers do not fit "
                                  f"one write request (FC 16 writes at most {_MAX_FC16})")
        if isinstance(value, float) and not math.isfinite(value):  # a float point's encode
            # takes NaN and infinities (the simulator's faults): a write never sends them
            raise InvalidArgument(f"{m.id}: point {label!r}: {value!r} is not a finite number")
    _check_overlaps(m, changes)
    return changes


def _span(c: Change) -> range:
    return range(c.point.address, c.point.address + c.point.count)


def _check_overlaps(m: Map, changes: Sequence[Change]) -> None:
    """Two values may share a register only as views of different bits."""
    for i, a in enumerate(changes):
        for b in changes[:i]:
            if a.point.table != b.point.table or not set(_span(a)) & set(_span(b)):
                continue
            if a.name == b.name:
                raise InvalidArgument(f"{m.id}: {a.name!r} is given twice")
            same = a.keep is not None and b.keep is not None and (
                a.point.address, a.point.count) == (b.point.address, b.point.count)
            if not same or any(~ka & ~kb & 0xFFFF for ka, kb in
                               zip(a.keep or (), b.keep or (), strict=True)):
                raise InvalidArgument(f"{m.id}: {a.name!r} and {b.name!r} share registers; "
                                      "write them in separate commands")


def requests(m: Map, changes: Sequence[Change], current: Mapping[int, int] | None = None
             ) -> list[WriteRequest]:
    """The fewest requests that write ``changes`` whole, in address order.
    ``current`` (address -> register, for views without ``mask_write``)
    fills in the bits a view leaves alone; without it such a request is
    marked ``rmw`` and shows the view's bits only."""
    limits = m.limits
    out: list[WriteRequest] = []
    regs: dict[int, int] = {}  # address -> register to write (holding)
    rmw: set[int] = set()
    owners: dict[int, list[str]] = {}
    masks: dict[int, tuple[int, int, list[str]]] = {}  # FC 22: address -> (and, or, names)
    coils: dict[int, tuple[int, str]] = {}
    for c in changes:
        p = c.point
        if p.table == "coil":
            coils[p.address] = (c.registers[0], c.name)
            continue
        if c.keep is not None and limits.mask_write:
            for k, (keep, bits) in enumerate(zip(c.keep, c.registers, strict=True)):
                if keep == 0xFFFF:  # none of its bits here (a wide view): nothing to send
                    continue
                a = p.address + k
                and_, or_, names = masks.get(a, (0xFFFF, 0, []))
                masks[a] = (and_ & keep, or_ | (bits & ~keep & 0xFFFF), [*names, c.name])
            continue
        if c.keep is not None:
            for k, (keep, bits) in enumerate(zip(c.keep, c.registers, strict=True)):
                if keep == 0xFFFF:
                    continue
                a = p.address + k
                if current is not None and a in current and a not in regs:
                    base = current[a]
                else:
                    base = regs.get(a, 0)
                    if current is None or a not in current:
                        rmw.add(a)
                regs[a] = (base & keep) | (bits & ~keep & 0xFFFF)
                owners.setdefault(a, []).append(c.name)
            continue
        for k, r in enumerate(c.registers):
            regs[p.address + k] = r
            owners.setdefault(p.address + k, []).append(c.name)
    for a in sorted(masks):
        and_, or_, owned = masks[a]
        out.append(WriteRequest(22, "holding", a, (and_, or_), tuple(owned)))
    out.extend(_runs(sorted(regs), regs, owners, rmw, limits.write_multiple == "always"))
    run: list[int] = []
    for a in [*sorted(coils), -1]:
        if run and (a != run[-1] + 1 or len(run) == _MAX_FC15):
            out.append(WriteRequest(5 if len(run) == 1 else 15, "coil", run[0],
                               tuple(coils[x][0] for x in run),
                               tuple(coils[x][1] for x in run)))
            run = []
        if a >= 0:
            run.append(a)
    return sorted(out, key=lambda r: (r.table, r.address))


def _runs(addresses: list[int], regs: Mapping[int, int], owners: Mapping[int, list[str]],
          rmw: set[int], always16: bool) -> list[WriteRequest]:
    """Adjacent registers in FC 16 requests (a point never split: a request
    ends only where no point continues), FC 06 for a lone register."""
    out: list[WriteRequest] = []
    run: list[int] = []

    def flush() -> None:
        if not run:
            return
        names = tuple(dict.fromkeys(n for a in run for n in owners[a]))
        fc = 16 if len(run) > 1 or always16 else 6
        out.append(WriteRequest(fc, "holding", run[0], tuple(regs[a] for a in run), names,
                           any(a in rmw for a in run)))
        run.clear()

    points: list[list[int]] = []  # the registers of each point (views with theirs), in order
    for a in addresses:
        if points and a == points[-1][-1] + 1 and set(owners[a]) & set(owners[a - 1]):
            points[-1].append(a)
        else:
            points.append([a])
    for span in points:  # greedy: a request ends only where the next point would not fit
        if run and (span[0] != run[-1] + 1 or len(run) + len(span) > _MAX_FC16):
            flush()
        run.extend(span)
    flush()
    return out


def label(p: Point, value: Value) -> Value:
    """A raw value as the name ``values`` gives it, where it gives one."""
    if p.values and isinstance(value, int) and not isinstance(value, bool):
        return p.values.get(value, value)
    return value


def decoded(p: Point, registers: Sequence[int], sf: int | None = None) -> Value:
    """One channel's value from its registers (bits), named where ``values``
    names it; ``sf``: its scale factor, for a ``scale_from`` point."""
    return label(p, decode_one(p, registers, sf)[0])


def check_budgets(budget: Budget, key: str, changes: Sequence[Change], where: str) -> None:
    """The :class:`~pymb.WriteRefused` (``where`` first) of the first of
    ``changes`` whose write budget, counted at ``key/NAME``, is spent."""
    for c in changes:
        limit = c.point.max_writes_per_hour
        if limit is not None and budget.spent(f"{key}/{c.name}", limit):
            raise WriteRefused(f"{where}: {c.name!r}: write budget spent ({limit} writes per "
                               "hour); nothing was sent", reason="budget", point=c.name)


def not_applied(where: str, failed: Sequence[tuple[Change, Value]],
                applied: dict[str, Any]) -> WriteNotApplied:
    """The :class:`~pymb.WriteNotApplied` of the points whose read back differs."""
    parts = [f"{c.name!r}: sent {c.value!r}, the device holds {found!r}" for c, found in failed]
    c, found = failed[0]
    done = f"; applied: {', '.join(applied)}" if applied else ""
    return WriteNotApplied(f"{where}: not applied: {'; '.join(parts)}{done}", point=c.name,
                           sent=c.value, found=found, applied=applied)


def note_applied(e: ModbusError, applied: Sequence[str]) -> None:
    """Say in ``e`` which points were written before it happened."""
    e.applied = list(applied)  # type: ignore[attr-defined]
    if applied and e.args:
        e.args = (f"{e.args[0]} (written before the failure: {', '.join(applied)})",
                  *e.args[1:])
