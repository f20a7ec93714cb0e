"""A simulated device for any map: :class:`MapSimDevice`.

It has exactly the registers (and bits) its map declares, plus the map's
``readable`` ranges (zeros); a read that touches any other address gets
exception 02, as a real device that lacks them does, so the planner's
fallbacks can be watched. Each point starts at its ``example`` value (the
same on every channel of a block), which a view of the same registers
without an example (a ``bit`` of a status word) leaves as it is; a point
without one, on registers no example sets, gets a value from a
seeded model: a gauge wanders around a seeded level (inside ``valid`` when
the map gives it), a counter counts up, a point with ``values`` takes its
first, text is the point's name. Writable points take writes (FC 05, 06,
15, 16) checked as the map checks them (whole points, inside ``valid``, else
exception 03); anything else is refused. A broadcast write is carried out.
A point whose ``min_firmware`` is above the device's ``firmware`` is absent.

The ``sensor`` fault puts a point that has ``markers`` (or a float's NaN) in
its no-value state for a while: ``channels`` names channels of a block.
A test holds values from the map alone: :meth:`MapSimDevice.pin` a
read-only point at a raw value, :meth:`~MapSimDevice.set_flags` bits of a
point with ``flags``, :meth:`~MapSimDevice.set_offline` a channel (each
block's ``offline`` marker), :meth:`~pymb.sim.mapimage.MapImage.set_identity`
a point of the ``identity`` group. The registers, the firmware's points
and channels are :class:`~pymb.sim.mapimage.MapImage`'s, the seeded model
:mod:`pymb.sim.seeded`'s.

A device with behaviours of its own (the CoolPro, the sensor hub) is a
subclass: it narrows :attr:`MapSimDevice.functions`, picks the exception
code of a malformed request, brings its own values (:meth:`_start`,
:meth:`_refresh`, :meth:`_channel_changed`), reacts to writes
(:meth:`_wrote`) and adds keys to its device spec (:attr:`spec_keys`);
everything else (registers, addresses, exceptions, writes, firmware, the
spec's options, the values a test holds) is the engine's and the map's.
"""

from __future__ import annotations

import math
import random
import struct
from array import array
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import replace
from typing import ClassVar

from pymb._native import MAX_READ_BITS, MAX_READ_REGISTERS, MAX_WRITE_BITS, MAX_WRITE_REGISTERS
from pymb.devices.mapspec import MapTarget
from pymb.errors import InvalidArgument
from pymb.maps import Map, Point
from pymb.maps.codec import decode_one, encode
from pymb.maps.types import TYPES
from pymb.sim.base import MAX_DELAY_S, ExceptionCode, Keys, _locked, exception_pdu
from pymb.sim.clock import SimClock
from pymb.sim.mapimage import TABLES as _TABLE
from pymb.sim.mapimage import MapImage
from pymb.sim.seeded import Wander, first_value, value_at
from pymb.wire import registers_to_wire

__all__ = ["MapSimDevice"]

_UPDATE_S = 0.1  #: the model's values are brought up to date at most this often
#: the function codes a map's device answers (reads and writes of its tables)
_ANSWERED = frozenset((1, 2, 3, 4, 5, 6, 15, 16))


class MapSimDevice(MapImage):
    """The device ``m`` describes, at ``address``; values from each point's
    ``example`` or the model seeded by ``seed``. ``firmware``: the version
    it runs (points with a higher ``min_firmware`` are absent; "" has all)."""

    #: function codes answered (None: the reads and writes of the four tables,
    #: 01..06, 15, 16); any other answers 01
    functions: ClassVar[frozenset[int] | None] = None
    #: the exception code of a malformed request or a quantity outside 1..max
    bad_request: ClassVar[int] = ExceptionCode.ILLEGAL_DATA_VALUE
    #: a device with behaviours of its own: its shipped map, the keys of its
    #: spec beside :data:`SIM_KEYS`, and map options it refuses (key -> why)
    builtin_map: ClassVar[Map | None] = None
    spec_keys: ClassVar[Keys] = {}
    #: the constructor's name of the wait before a reply (a check names it)
    delay_arg: ClassVar[str] = "delay"
    refused: ClassVar[Mapping[str, str]] = {}

    def __init__(self, m: Map, address: int | None = None, *, baud: int = 9600,
                 seed: int = 0, clock: SimClock | None = None, dynamic: bool = True,
                 delay: float | tuple[float, float] = 0.0, firmware: str = "") -> None:
        super().__init__(m, address, baud=baud, seed=seed, clock=clock)
        self.dynamic = dynamic
        span = delay if isinstance(delay, tuple) else (delay, delay)
        if not 0.0 <= span[0] <= span[1] <= MAX_DELAY_S:
            raise InvalidArgument(f"{m.id}: {self.delay_arg} must be 0..{MAX_DELAY_S:g} s "
                                  f"(or a low, high range), got {delay!r}")
        #: seconds from a request's end to the reply (a range: drawn per request)
        self.delay = delay
        if firmware:
            self.firmware = firmware
        else:
            self._build_have()
        self._model: list[tuple[Point, int, Wander]] = []
        self._t0 = self.clock.now()  # counters count from here
        self._faulted: dict[tuple[str, int], tuple[float, list[int]]] = {}  # -> until, regs
        self._pinned: set[tuple[str, int]] = set()  # written: the model leaves them be
        self._pins: dict[tuple[str, int], tuple[int, list[int]]] = {}  # -> raw, regs before
        self._flags: dict[str, dict[int, float]] = {}  # flags point -> raised bit -> until
        self._flags_added: dict[str, int] = {}  # flags point -> bits raised over its value
        self._forced: dict[int, bool] = {}  # channel index -> offline (True) / online
        self._offline_until: dict[int, float] = {}  # channel index -> simulated expiry
        self._updated = -math.inf
        self._start(random.Random(seed))

    @classmethod
    def _from_spec(cls, target: MapTarget, args: dict[str, object], *, seed: int,
                   clock: SimClock | None) -> MapSimDevice:
        """The device a parsed spec names (``args``: its :data:`SIM_KEYS`
        and :attr:`spec_keys` as constructor arguments, ``delay`` as the
        constructor names it); a device of a :attr:`builtin_map` takes no map."""
        if "delay" in args:
            args[cls.delay_arg] = args.pop("delay")
        head = (target.map,) if cls.builtin_map is None else ()
        return cls(*head, target.address, seed=seed, clock=clock, **args)  # type: ignore[arg-type, call-arg]

    # -- held values ----------------------------------------------------------------------

    @_locked
    def pin(self, name: str, *where: int) -> None:
        """``pin(name, raw)`` or ``pin(name, channel, raw)``: make a read-only
        point (one channel of a block) read ``raw`` until :meth:`unpin`."""
        channel, raw = where if len(where) == 2 else (1, *where)
        p, a = self._point(name, channel)
        if p.writable:
            raise InvalidArgument(f"{name} is writable: write it rather than pin it")
        before = self._pins.get((name, channel), (0, list(self._images[p.table][a:a + p.count])))
        self._pins[(name, channel)] = (raw & ((1 << 16 * p.count) - 1), before[1])

    @_locked
    def unpin(self, name: str | None = None, channel: int | None = None) -> None:
        """Let pinned points (all, ``name``'s, or one channel's) follow the model again."""
        for (n, c), (_, before) in list(self._pins.items()):
            if name in (None, n) and channel in (None, c):
                p, a = self._point(n, c)
                self._images[p.table][a:a + p.count] = array("H", before)
                del self._pins[(n, c)]
        self._updated = -math.inf  # the next read brings them up to date

    @_locked
    def set_flags(self, name: str, mask: int, seconds: float | None = None) -> None:
        """Raise the bits in ``mask`` of read-only flags point ``name``
        (undeclared bits too), for ``seconds`` of simulated time or until
        :meth:`clear_flags`; they read raised over the point's own value."""
        p = self._point(name)[0]
        if p.writable or not p.flags:
            raise InvalidArgument(f"{name} is not a read-only point with flags")
        top = (1 << 16 * p.count) - 1
        if not 0 < mask <= top:
            raise InvalidArgument(f"{name} mask must be 1..0x{top:X}, got {mask!r}")
        until = math.inf if seconds is None else self.clock.now() + seconds
        self._flags.setdefault(name, {}).update(
            {1 << b: until for b in range(16 * p.count) if mask >> b & 1})

    @_locked
    def clear_flags(self, name: str, mask: int = -1) -> None:
        """Drop bits of ``name`` raised by :meth:`set_flags` (all by default)."""
        self._point(name)
        self._flags[name] = {b: t for b, t in self._flags.get(name, {}).items() if not b & mask}

    def _raised(self, name: str, t: float) -> int:
        """The bits of flags point ``name`` raised by :meth:`set_flags` at time ``t``."""
        forced = self._flags.get(name)
        if not forced:
            return 0
        self._flags[name] = forced = {b: until for b, until in forced.items() if until > t}
        return sum(forced)

    @_locked
    def set_offline(self, channel: int | Iterable[int], offline: bool | None = True,
                    seconds: float | None = None) -> None:
        """Force ``channel`` offline (True), online (False) or back to the
        value model (None); with ``seconds``, offline for that long in
        simulated time. Offline, every block with an ``offline`` marker reads
        it on that channel."""
        now = self.clock.now()
        for ci in self._cis(channel):
            if seconds is not None and offline:
                self._offline_until[ci] = now + seconds
            else:
                self._offline_until.pop(ci, None)
                if offline is None:
                    self._forced.pop(ci, None)
                else:
                    self._forced[ci] = bool(offline)
            self._channel_changed(ci, now)

    def _held_offline(self, ci: int) -> bool | None:
        """Channel index ``ci`` held offline (True) or online (False) by
        :meth:`set_offline`; None: the value model says."""
        forced = self._forced.get(ci)
        return forced if forced is not None else True if ci in self._offline_until else None

    def _channel_changed(self, ci: int, t: float) -> None:
        """Channel index ``ci`` was set offline or back at time ``t``: its
        blocks' ``offline`` markers, held as a sensor fault is."""
        off = bool(self._held_offline(ci))
        until = math.inf if self._forced.get(ci) else self._offline_until.get(ci, math.inf)
        for p in self.map.points.values():
            raw = next((r for r, state in p.markers.items() if state == "offline"), None)
            key = (p.name, ci + 1)
            if raw is None or not p.block or ci >= p.channels:
                continue
            a = p.address_of(ci + 1)
            img = self._images[p.table]
            if off:
                before = self._faulted.get(key, (0.0, list(img[a:a + p.count])))[1]
                self._put_raw(p.name, raw, ci + 1)
                self._faulted[key] = (until, before)
            elif key in self._faulted:
                img[a:a + p.count] = array("H", self._faulted.pop(key)[1])

    def _now(self) -> None:
        """Bring every value to the clock's time: the model's, raised flags, then the pins."""
        self._refresh()
        if self._flags or self._flags_added:
            t = self.clock.now()
            for name in {*self._flags, *self._flags_added}:
                bits = self._raised(name, t)
                p, a = self._point(name)
                raw = self._raw(p, a) & ~self._flags_added.pop(name, 0)
                if bits & ~raw:
                    self._flags_added[name] = bits & ~raw
                self._put_raw(name, raw | bits)
            self._flags = {n: f for n, f in self._flags.items() if f}
        for (name, c), (raw, _) in self._pins.items():
            self._put_raw(name, raw, c)

    # -- values -----------------------------------------------------------------------

    def _start(self, rng: random.Random) -> None:
        """The values at start: each point's example, else the seeded model's."""
        m = self.map
        # an example wins over the views of its registers that have none: points
        # with an example go last, and one without that shares a register with
        # one that has an example is left as the example makes it
        shown: dict[str, bytearray] = {t: bytearray(0x10000) for t in _TABLE.values()}
        for p in m.points.values():
            if p.example is not None:
                for c in range(1, p.channels + 1):
                    a = p.address_of(c)
                    shown[p.table][a:a + p.count] = b"\x01" * p.count
        # scale factors first: the values they scale are encoded with them
        sfs = {p.scale_from for p in m.points.values()}
        for p in sorted(m.points.values(),
                        key=lambda p: (p.name not in sfs, p.example is not None)):
            for c in range(1, p.channels + 1):
                a = p.address_of(c)
                if p.example is not None or not any(shown[p.table][a:a + p.count]):
                    self._init(p, c, rng)

    def _init(self, p: Point, channel: int, rng: random.Random) -> None:
        value: object
        if p.example is not None:
            value = p.example[channel - 1] if p.block and isinstance(p.example, list) \
                else p.example
        else:
            value, wander = first_value(p, rng, self._sf_of(p))
            if wander is not None:
                self._model.append((p, channel, wander))
        self._put(p, channel, value)

    def _refresh(self) -> None:
        """Bring the model's values to the clock's time, and end the faults
        and offline channels whose time is up (values that do not move too)."""
        t = self.clock.now()
        if self.dynamic:
            if t - self._updated < _UPDATE_S:
                return
            self._updated = t
            for p, c, wander in self._model:
                if (p.name, c) in self._faulted or (p.name, c) in self._pinned:
                    continue
                try:
                    self._put(p, c, value_at(p, wander, t, self._t0))
                except InvalidArgument:
                    continue  # outside what the point can hold: keep the last value
        for ci, until in list(self._offline_until.items()) if self._offline_until else ():
            if until <= t:
                del self._offline_until[ci]
        for (name, c), (until, regs) in list(self._faulted.items()):
            if t >= until:
                del self._faulted[(name, c)]
                p = self.map.points[name]
                a = p.address_of(c)
                self._images[p.table][a:a + p.count] = array("H", regs)

    # -- requests ---------------------------------------------------------------------

    def turnaround(self) -> float:
        """Seconds from the end of a request to the start of the reply
        (``delay``, drawn from its range when it is one)."""
        d = self.delay
        return self.rng.uniform(*d) if isinstance(d, tuple) else d

    def _span(self, table: str, address: int, count: int) -> bool:
        if address + count > 0x10000:
            return False
        return self._have[table][address:address + count].count(1) == count

    def handle(self, pdu: bytes) -> bytes | None:
        """The reply to one request PDU, checked in [MB-AP] 6's order: the
        function code (01), the PDU's size, the quantity and the byte count
        (:attr:`bad_request`), the addresses (02)."""
        fc = pdu[0] if pdu else 0
        if fc not in (_ANSWERED if self.functions is None else self.functions):
            return exception_pdu(fc, ExceptionCode.ILLEGAL_FUNCTION)
        if len(pdu) < 5 or (fc <= 6 and len(pdu) != 5):
            return exception_pdu(fc, self.bad_request)
        address, n = struct.unpack(">HH", pdu[1:5])
        if fc in _TABLE:
            table = _TABLE[fc]
            if not 1 <= n <= (MAX_READ_BITS if fc <= 2 else MAX_READ_REGISTERS):
                return exception_pdu(fc, self.bad_request)
            if not self._span(table, address, n):
                return exception_pdu(fc, ExceptionCode.ILLEGAL_DATA_ADDRESS)
            self._now()
            regs = self._images[table][address:address + n]
            if fc <= 2:
                out = bytearray((n + 7) // 8)
                for i, v in enumerate(regs):
                    if v:
                        out[i // 8] |= 1 << (i % 8)
                return bytes((fc, len(out))) + bytes(out)
            return bytes((fc, 2 * n)) + registers_to_wire(regs, in_place=True)  # a fresh slice
        if fc == 5 and n not in (0x0000, 0xFF00):  # [MB-AP] 6.5: ON or OFF, nothing else
            return exception_pdu(fc, self.bad_request)
        if fc in (5, 6):
            return self._write(fc, "coil" if fc == 5 else "holding", address,
                               [int(n == 0xFF00)] if fc == 5 else [n], pdu)
        # 15, 16 ([MB-AP] 6.11, 6.12): a quantity 1..max, its byte count, its data
        limit, size = (MAX_WRITE_REGISTERS, 2 * n) if fc == 16 else (MAX_WRITE_BITS, (n + 7) // 8)
        if not 1 <= n <= limit or len(pdu) != 6 + size or pdu[5] != size:
            return exception_pdu(fc, self.bad_request)
        data = pdu[6:]
        values = (list(struct.unpack(f">{n}H", data)) if fc == 16
                  else [data[i // 8] >> (i % 8) & 1 for i in range(n)])
        return self._write(fc, "holding" if fc == 16 else "coil", address, values, pdu[:5])

    def handle_broadcast(self, pdu: bytes) -> None:
        """Standard Modbus ([MB-SL] 2.1): a broadcast write is carried out
        without a reply; broadcast reads are ignored."""
        if pdu and pdu[0] in (5, 6, 15, 16):
            self.handle(pdu)

    def _write(self, fc: int, table: str, address: int, values: list[int],
               echo: bytes) -> bytes:
        """Store ``values`` at ``address`` if writable points cover them
        exactly, each inside its ``valid`` range."""
        end = address + len(values)
        img = self._images[table]
        covered = bytearray(len(values))
        hits: list[tuple[Point, int]] = []
        for p in self.map.points.values():
            if p.table != table or not p.writable:
                continue
            for c in range(1, self._channels_of(p) + 1):
                a = p.address_of(c)
                if address <= a and a + p.count <= end:
                    covered[a - address:a - address + p.count] = b"\x01" * p.count
                    hits.append((p, c))
        if covered.count(1) != len(values):
            return exception_pdu(fc, ExceptionCode.ILLEGAL_DATA_ADDRESS)
        for p, c in hits:
            if p.valid is not None:
                a = p.address_of(c) - address
                v = decode_one(p, values[a:a + p.count], self._sf_of(p))[0]
                if isinstance(v, (int, float)) and not p.valid[0] <= v <= p.valid[1]:
                    return exception_pdu(fc, ExceptionCode.ILLEGAL_DATA_VALUE)
        img[address:end] = array("H", values)
        for p in self.map.points.values():
            if p.table == table:
                for c in range(1, p.channels + 1):
                    a = p.address_of(c)
                    if a < end and address < a + p.count:
                        self._pinned.add((p.name, c))
        for p, c in hits:
            self._wrote(p, c)
        return echo

    def _wrote(self, p: Point, channel: int) -> None:
        """Point ``p`` (its ``channel``) was just written: a device's own reaction."""

    def sensor_fault(self, rng: random.Random, seconds: float, *, bits: int | None = None,
                     channels: Sequence[int] | None = None) -> str:
        """Put points in their no-value state for ``seconds``: a block's
        ``channels`` (default one at random) or a point with markers or NaN."""
        choices = [p for p in self.map.points.values()
                   if p.markers or TYPES[p.type].family == "float"]
        if not choices:
            return "no point can show a sensor fault"
        p = rng.choice(choices)
        chans = list(channels) if channels and p.block else [rng.randrange(p.channels) + 1]
        until = self.clock.now() + seconds
        for c in chans:
            if not 1 <= c <= p.channels:
                continue
            a = p.address_of(c)
            img = self._images[p.table]
            if p.markers:
                raw = next(iter(p.markers))
                regs = list(struct.unpack(f">{p.count}H", raw.to_bytes(2 * p.count, "big")))
            else:
                regs = encode(replace(p, valid=None, values={}), math.nan, check_access=False)
            before = self._faulted.get((p.name, c), (0.0, list(img[a:a + p.count])))[1]
            img[a:a + p.count] = array("H", regs)
            self._faulted[(p.name, c)] = (until, before)
        return f"{p.name} channels {chans} without a value for {seconds:g} s"

    def describe(self) -> str:
        """One line for the command line's banner."""
        what = " ".join(x for x in (self.map.device.manufacturer, self.map.device.model) if x)
        return (f"{self.map.id} at address {self.address} ({self.baud} 8N1)"
                + (f": {what}" if what else "") + f", {len(self.map.points)} points")

