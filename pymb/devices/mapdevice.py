"""Any Modbus device from its map: :class:`MapDevice`.

    from pymb import maps
    from pymb.devices import MapDevice

    with pymb.RtuClient("/dev/ttyUSB0", 9600) as client:
        meter = MapDevice(client, maps.load("eastron-sdm120.toml"), address=3)
        meter.read(group="fast")           # {"voltage_v": 230.5, ...}
        meter.write("relay_on", True)

A read plans its requests with the device's limits and timing
(:mod:`pymb.maps.planner`), reads each into one buffer the device keeps,
and decodes every point from it. Exception 02 or 03 to a request that read
registers nobody asked for makes the planner stop bridging there and the
same read asks again without them; to a request of wanted points only, each
is asked alone, and one the device refuses alone reads None (state
``unsupported``) until it is tried again ``offline_retry`` seconds later.
"""

from __future__ import annotations

import math
from array import array
from collections.abc import Callable, Iterable, Mapping, Sequence
from functools import partial
from typing import Any, TypeVar

from pymb.client import Client
from pymb.devices import writeio
from pymb.devices.mapfetch import Fetcher, Image, Read, mark_unread
from pymb.devices.mapreading import MapReading
from pymb.devices.mapwrite import (
    Budget,
    Outcome,
    WriteBudget,
    WriteRequest,
    check,
    check_budgets,
    decoded,
    note_applied,
    requests,
)
from pymb.errors import IllegalDataAddress, IllegalDataValue, InvalidArgument, ModbusError
from pymb.maps import Decoder, Map, Point, Value
from pymb.maps.device_plan import PointPlanner, map_planner
from pymb.maps.model import check_address, check_group, did_you_mean
from pymb.maps.planner import Line, ReadPlan
from pymb.maps.types import STATES
from pymb.wire import DEFAULT_BAUD, bits_per_char

__all__ = ["MapDevice", "check_seconds", "prepared_read"]

#: The line speed a plan is priced at when the client has none (TCP).
DEFAULT_BAUDRATE = DEFAULT_BAUD
_CACHED = 64  #: selections (and their buffers) kept per device
_NOT_READ = STATES.index("not_read")
_UNSEEN = object()  #: channels a read is never found again by
T = TypeVar("T")


def check_seconds(what: str, value: object) -> None:
    """An :class:`~pymb.InvalidArgument` unless ``value`` is a number of
    seconds (not a bool) in 0..10."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value <= 10:
        raise InvalidArgument(f"{what} must be 0..10 s, got {value!r}")


class MapDevice:
    """The device ``m`` describes, at unit id ``address`` on ``client`` (an
    :class:`~pymb.RtuClient`, :class:`~pymb.TcpClient` or
    :class:`~pymb.RtuOverTcpClient`).

    ``options``: the map's options for this device (``{"channels": 50}``).
    ``baudrate``: the line speed plans are priced at, where the client has
    none (a TCP gateway's serial side; default 9600). The map's timing is
    honoured on the wire: ``inter_request_gap`` of silence before each
    request, ``turnaround`` of silence after each reply (for every map device
    on the same client), ``after_connect`` before the first request on a new
    connection, and ``response_timeout`` as the reply timeout of its requests.
    ``budget``: where writes are counted against ``max_writes_per_hour``
    (a :class:`~pymb.devices.mapwrite.WriteBudget`; one of its own by default).
    ``busy_retries`` / ``busy_backoff``: for a device that answers exception
    04 when busy (the sensor hub): a read request answered 04 is asked again
    up to ``busy_retries`` times, ``busy_backoff`` seconds later (doubling
    each time), before the :class:`~pymb.DeviceFailure` is raised.
    ``plan_turnaround``: the answer delay plans are priced at, where it is
    not the map's ``turnaround`` (no silence is kept for it on the wire).
    ``split_on``: the exception codes a read falls back on, where the map
    says ``split_on_exception`` (02 and 03 by default; the sensor hub's
    firmware answers 02 alone for a block it lacks).
    """

    def __init__(self, client: Client, m: Map, address: int | None = None, *,
                 options: Mapping[str, object] | None = None,
                 baudrate: int | None = None, budget: Budget | None = None,
                 busy_retries: int = 0, busy_backoff: float = 0.02,
                 plan_turnaround: float | None = None,
                 split_on: Iterable[int] = (2, 3)) -> None:
        if not isinstance(client, Client):
            raise InvalidArgument(f"a map device needs a pymb client (RtuClient, TcpClient, "
                                  f"RtuOverTcpClient), got {type(client).__name__}")
        if not isinstance(m, Map):
            raise InvalidArgument(f"a map device needs a map (pymb.maps.load or "
                                  f"pymb.maps.builtin), got {type(m).__name__}")
        if baudrate is not None and (isinstance(baudrate, bool) or not isinstance(baudrate, int)
                                     or baudrate <= 0):
            raise InvalidArgument(f"baudrate is a number of bit/s, got {baudrate!r}")
        if options is not None and not isinstance(options, Mapping):
            raise InvalidArgument(f"options are a mapping of names to values, "
                                  f"got {type(options).__name__}")
        if isinstance(busy_retries, bool) or not isinstance(busy_retries, int) or not (
                0 <= busy_retries <= 100):
            raise InvalidArgument(f"busy_retries must be 0..100, got {busy_retries!r}")
        check_seconds("busy_backoff", busy_backoff)
        if options:
            m = m.configure(options)
        self.client = client
        self.map = m
        self.address = address = check_address(m, address)
        rate = getattr(client, "baudrate", None) or baudrate or DEFAULT_BAUDRATE
        line = Line(int(rate), bits_per_char(getattr(client, "parity", "N"),
                                              getattr(client, "stop_bits", 1),
                                              getattr(client, "data_bits", 8)))
        self._planner, mi = map_planner(m, line)
        if plan_turnaround is not None:
            check_seconds("plan_turnaround", plan_turnaround)
            pl = self._planner.line
            self._planner.line = Line(pl.baudrate, pl.bits_per_char, plan_turnaround,
                                      pl.inter_request_gap)
        self._mi = mi
        self._points: tuple[Point, ...] = mi.points
        self._first = mi.first
        self._index = {p.name: i for i, p in enumerate(self._points)}
        self._selections: dict[tuple[tuple[str, ...], str | None], tuple[int, ...]] = {}
        # per selection (points, channels): its Read and the output slots of
        # the block channels it does not read
        self._reads: dict[tuple[tuple[int, ...], tuple[int, ...] | None],
                          tuple[Read, tuple[tuple[Any, int], ...]]] = {}
        #: the last read's names, group, channels, Read and unread slots: a
        #: poller asking the same again finds it
        self._last: tuple[tuple[str, ...], str | None, object, Read,
                          tuple[tuple[Any, int], ...]] | None = None
        self._fetcher = Fetcher(client, m, address, self._planner)
        refusals = {2: IllegalDataAddress, 3: IllegalDataValue}
        try:
            codes = set(split_on)
        except TypeError:
            raise InvalidArgument(f"split_on is a list of exception codes (2, 3), "
                                  f"got {split_on!r}") from None
        if not codes <= set(refusals):
            raise InvalidArgument(f"split_on takes the exception codes 2 and 3, "
                                  f"got {sorted(codes, key=repr)}")
        self._fetcher.refusals = tuple(refusals[c] for c in sorted(codes))
        self._fetcher.busy_retries = busy_retries
        self._fetcher.busy_backoff = float(busy_backoff)
        # The line's lock, the client's own (reentrant), held for each whole read and
        # write: no other device's or thread's request comes between its requests.
        self._lock = self._fetcher.quiet.lock
        self.states: dict[str, Any] = {}  #: the last read's state of each point read
        #: the writes counted against ``max_writes_per_hour`` (in memory unless given)
        self.budget: Budget = budget if budget is not None else WriteBudget()

    @property
    def planner(self) -> PointPlanner:
        """The device's read planner: its plans and what the device taught
        it (the points it refused, :attr:`PointPlanner.unsupported`)."""
        return self._planner

    # -- what to read -----------------------------------------------------------------

    def _selection(self, names: Sequence[str], group: str | None) -> tuple[int, ...]:
        key = (tuple(names), group)
        m = self.map
        try:
            chosen = self._selections.get(key)
        except TypeError:  # a name or group that is not text (a list): say so
            chosen = None
            for n in names:
                m.point(n)
            check_group(m, group)
        if chosen is not None:
            return chosen
        check_group(m, group)
        if names and group is not None:
            raise InvalidArgument("read points by name or by group, not both")
        if group is not None and group not in m.groups:
            hint = did_you_mean(group, list(m.groups))
            raise InvalidArgument(f"{m.id}: no group {group!r}{hint}")
        if names:
            out = []
            for n in names:
                p = m.point(n)  # MapError with a did-you-mean
                if p.access == "w":
                    raise InvalidArgument(f"{m.id}: point {n!r} is write-only")
                out.append(self._index[n])
        else:
            out = self._mi.group(group)
        # a scale_from point's scale factor is read with it
        chosen = tuple(dict.fromkeys(self._index[n] for n in m.with_scale_factors(
            self._points[i].name for i in out)))
        if len(self._selections) >= _CACHED:
            self._selections.clear()  # many different selections: keep memory bounded
        self._selections[key] = chosen
        return chosen

    def _channels(self, points: tuple[int, ...], channels: Any) -> tuple[int, ...] | None:
        """``channels`` (of the blocks among ``points``) checked: a sorted
        tuple, None for all."""
        if channels is None:
            return None
        try:
            chosen = tuple(sorted(set(channels)))
        except TypeError:
            raise InvalidArgument(f"channels is a list of channel numbers, e.g. range(1, 13), "
                                  f"got {channels!r}") from None
        blocks = [self._points[i] for i in points if self._points[i].block]
        most = min((p.channels for p in blocks), default=0)
        for c in chosen:
            if isinstance(c, bool) or not isinstance(c, int) or not 1 <= c <= most:
                raise InvalidArgument(f"{self.map.id}: channel must be 1..{most}, got {c!r}")
        return chosen

    def _read_of(self, names: tuple[str, ...], group: str | None,
                 channels: Any = None) -> tuple[Read, tuple[tuple[Any, int], ...]]:
        """The selection's :class:`Read`, made on its first read: a buffer
        per table, from its first point's register (bit) to its last's, each
        request read in place, and the compiled decoder that walks it in one
        C call; with it, the output slots of the block channels not read."""
        points = self._selection(names, group)
        chans = self._channels(points, channels)
        key = (points, chans)
        got = self._reads.get(key)
        if got is None:
            tables: dict[str, list[str]] = {}
            for i in points:
                p = self._points[i]
                tables.setdefault(p.table, []).append(p.name)
            images = {}
            for t, ns in tables.items():
                dec = Decoder(self.map, ns)
                images[t] = Image(dec.address, array("H", bytes(2 * dec.count)), dec)
            items = self._mi.wanted(points)
            skipped: list[tuple[Any, int]] = []
            if chans is not None:
                keep = set(chans)
                items = []
                for i in points:
                    p, k0 = self._points[i], self._first[i]
                    if not p.block:
                        items.append(k0)
                        continue
                    dec = images[p.table].decoder
                    slot = dec.slot(p.name)
                    for c in range(1, p.channels + 1):
                        if c in keep:
                            items.append(k0 + c - 1)
                        else:
                            skipped.append((dec.buffers, slot + c - 1))
            got = (Read(points, tuple(items), images), tuple(skipped))
            if len(self._reads) >= _CACHED:
                self._reads.clear()  # many different selections: keep memory bounded
            self._reads[key] = got
        # a list may change before the next read: only a tuple is found again by identity
        self._last = (names, group, channels if channels is None or type(channels) is tuple
                      else _UNSEEN, got[0], got[1])
        return got

    def plan(self, group: str | None = None, *names: str,
             channels: Iterable[int] | None = None) -> ReadPlan:
        """The requests a read of ``group`` (or of the named points; all by
        default; of a block, only ``channels`` if given) makes now, with
        their predicted wire time."""
        if channels is None:
            return self._planner.plan(tuple(self._mi.wanted(self._selection(names, group))))
        return self._planner.plan(self._read_of(names, group, channels)[0].items)

    # -- reads ------------------------------------------------------------------------

    def read(self, *names: str, group: str | None = None) -> dict[str, Value]:
        """The named points, or the points of ``group``, or every readable
        point: name -> value (a list for a block; None where there is no
        value, and why in :attr:`states`)."""
        last = self._last
        r = last[3] if last is not None and last[0] == names and last[1] == group and (
            last[2] is None) else self._read_of(names, group)[0]
        with self._lock:
            self._fetcher.fetch(r)
            return self._decode(r.points, r.images)

    def read_into(self, *names: str, group: str | None = None,
                  channels: Iterable[int] | None = None) -> tuple[Decoder, ...]:
        """Read as :meth:`read` does, but build no dict: the values stay in
        the C decoder's arrays, one :class:`~pymb.maps.Decoder` per table of
        the selection (``d.buffers.values[d.slot(name) + channel - 1]``, its
        state in ``d.buffers.states``; NaN and ``unsupported`` where the
        device refused a point). The same decoders and arrays come back on
        every read of the same selection: a poller's steady state allocates
        nothing for the values. ``channels`` (1-based): only these channels
        of the blocks are asked for, the others are NaN and ``not_read``."""
        last = self._last
        if last is not None and last[0] == names and last[1] == group and last[2] is channels:
            return self._read_ready(last[3], last[4])
        return self._read_ready(*self._read_of(names, group, channels))

    def _read_ready(self, r: Read, skipped: tuple[tuple[Any, int], ...]
                    ) -> tuple[Decoder, ...]:
        lock = self._lock  # acquired and released: a with block binds its methods each time
        lock.acquire()
        try:
            return self._read_held(r, skipped)
        finally:
            lock.release()

    def _read_held(self, r: Read, skipped: tuple[tuple[Any, int], ...]) -> tuple[Decoder, ...]:
        """:meth:`_read_ready`'s read, the line's lock held."""
        decoded = self._fetcher.fetch(r, True)  # in the read's C call, if it could
        for decode, buffers, registers in r.decodes:
            if not decoded:
                decode()
            buffers.registers = registers
        if self._fetcher.marked:
            mark_unread(self._fetcher.unread, r.points, self._points, self._first, r.images)
        if skipped:
            nan, code = math.nan, _NOT_READ
            for b, slot in skipped:
                b.values[slot] = nan
                b.states[slot] = code
        return r.decoders

    def fetch(self, *names: str,
              group: str | None = None) -> tuple[tuple[Decoder, array[int]], ...]:
        """Read as :meth:`read_into` does, but decode nothing: per table of
        the selection, its decoder and the registers the requests read, from
        the decoder's ``address`` (the same arrays on every read of the same
        selection, valid until the next). For a view that decodes them
        itself (the sensor hub's reading); where the device refused a point,
        its registers are what they were (see :attr:`planner`)."""
        last = self._last
        if last is not None and last[0] == names and last[1] == group and last[2] is None:
            r = last[3]
        else:
            r = self._read_of(names, group)[0]
        lock = self._lock  # acquired and released, as in _read_ready
        lock.acquire()
        try:
            self._fetcher.fetch(r)
        finally:
            lock.release()
        return r.fetched

    def read_group(self, group: str | None = None) -> MapReading:
        """Read ``group`` (every readable point for None) as the logger keeps
        it: a :class:`~pymb.devices.mapreading.MapReading` with the registers
        the requests read (laid out as
        :func:`~pymb.devices.mapreading.group_layout` says), copied."""
        values = self.read(group=group)
        images = self._read_of((), group)[0].images
        regs = array("H")
        for image in images.values():
            regs.extend(image.registers)
        gone = tuple(n for n, s in self.states.items()
                     if s == "unsupported" or (isinstance(s, list) and "unsupported" in s))
        return MapReading(self.map, group, values, dict(self.states), regs, gone)

    def _decode(self, points: Sequence[int], images: dict[str, Image]) -> dict[str, Value]:
        """Every table's registers decoded in one C call each; points the
        device refused read None (``unsupported``)."""
        values: dict[str, Value] = {}
        states: dict[str, Any] = {}
        for image in images.values():
            dec = image.decoder
            b = dec.decode(image.registers)
            values.update(dec.values(b))
            states.update(dec.states(b))
        if self._fetcher.marked:
            unread = self._fetcher.unread
            for i in points:
                p = self._points[i]
                k0 = self._first[i]
                if not any(unread[k0:k0 + p.channels]):
                    continue
                if p.block:
                    v, st = values[p.name], states[p.name]
                    assert isinstance(v, list)
                    for c in range(p.channels):
                        if unread[k0 + c]:
                            v[c], st[c] = None, "unsupported"
                else:
                    values[p.name], states[p.name] = None, "unsupported"
        names = [self._points[i].name for i in points]
        self.states = {n: states[n] for n in names}
        return {n: values[n] for n in names}

    # -- writes -----------------------------------------------------------------------

    def write(self, name: str, value: object, *, channel: int | None = None,
              verify: bool = True) -> Value:
        """Write ``value`` to a writable point (one ``channel`` of a block,
        from 1) and return the value read back (None with ``verify=False``
        or for a write-only point). Everything is checked before any byte is
        sent (:class:`~pymb.InvalidArgument`); a spent write budget is a
        :class:`~pymb.WriteRefused`; a device that answers but holds another
        value raises :class:`~pymb.WriteNotApplied`."""
        return self.write_points([(name, channel, value)], verify=verify)[0].after

    def write_many(self, values: Mapping[str, object], *, verify: bool = True
                   ) -> dict[str, Value]:
        """Write ``{name: value}`` (a block's channel as ``name_N``) with the
        fewest requests that keep each point whole, checked whole first:
        one refused value writes nothing. Returns ``{name: value read back}``."""
        if not isinstance(values, Mapping):
            raise InvalidArgument(f"write_many takes a mapping of point names to values, "
                                  f"got {type(values).__name__}")
        out = self.write_points([(n, None, v) for n, v in values.items()], verify=verify)
        return {o.name: o.after for o in out}

    def plan_write(self, values: Mapping[str, object]) -> list[WriteRequest]:
        """The requests :meth:`write_many` would send, checked as it checks;
        nothing is sent (``pymb write --dry-run``)."""
        items = [(n, None, v) for n, v in values.items()]
        changes = check(self.map, items, self._scale_factors(items))
        return requests(self.map, changes)

    def _scale_factors(self, items: Sequence[tuple[str, int | None, object]]
                       ) -> dict[str, int | None]:
        return writeio.scale_factors(self.client, self.address, self._fetcher, self.map, items)

    def write_points(self, items: Sequence[tuple[str, int | None, object]], *,
                     verify: bool = True, before: bool = False) -> list[Outcome]:
        """Write ``(name, channel, value)`` items (see :mod:`pymb.devices.mapwrite`)
        and say what became of each: with ``before``, each point is read
        first. A point with a write budget is always read first: a value
        the device already holds is not sent, and does not count."""
        m = self.map
        changes = check(m, items, self._scale_factors(items))
        key = f"{m.id}:{self.address}"
        check_budgets(self.budget, key, changes, key)
        outcomes = [Outcome(c.name, c.value) for c in changes]
        rmw = not m.limits.mask_write
        with self._lock, self._fetcher.map_timeout():
            self._fetcher.after_connect()
            first = [c for c in changes if (c.point.access != "w" and (
                before or c.point.max_writes_per_hour is not None))
                or (rmw and c.view)]
            current = (writeio.read_spans(self.client, self.address, self._fetcher, first)
                       if first else {})
            todo = []
            for c, o in zip(changes, outcomes, strict=True):
                regs = writeio.regs_of(current, c)
                if regs is not None and c.point.access != "w" and (
                        before or c.point.max_writes_per_hour is not None):
                    o.before = decoded(c.point, regs, c.sf)
                    if c.point.max_writes_per_hour is not None and \
                            tuple(regs) == c.merged(regs):
                        o.after, o.applied = o.before, True  # held already: not sent
                        continue
                todo.append(c)
            holding = {a: v for (t, a), v in current.items() if t == "holding"}
            written: list[str] = []
            for r in requests(m, todo, holding):
                for n in r.names:
                    c = next(c for c in todo if c.name == n)
                    if c.point.max_writes_per_hour is not None:
                        self.budget.count(f"{key}/{n}")
                try:
                    writeio.send(self.client, self.address, self._fetcher, r)
                except ModbusError as e:
                    note_applied(e, written)
                    raise
                written.extend(r.names)
            for o in outcomes:
                o.sent = o.sent or o.name in written
            if verify:
                writeio.verify(self.client, self.address, self._fetcher, todo, outcomes, key)
        return outcomes

    def __repr__(self) -> str:
        return f"<MapDevice {self.map.id}:{self.address} on {self.client.port}>"


def prepared_read(device: MapDevice,
                  then: Callable[[tuple[tuple[Decoder, array[int]], ...]], Callable[[], T]],
                  *names: str, group: str | None = None,
                  channels: Iterable[int] | None = None, decode: bool = True) -> Callable[[], T]:
    """The selection of :meth:`MapDevice.read_into` made ready for a view that
    reads it over and over (the CoolPro's telemetry): a call that reads it as
    ``read_into`` does (without ``decode``: as :meth:`MapDevice.fetch` does)
    and returns what ``then(fetched)`` returned calls, holding the line's lock
    (:meth:`~pymb.devices.mapfetch.Fetcher.prepared`); ``fetched``: per table,
    the decoder the read fills and the registers it reads into."""
    r, skipped = device._read_of(names, group, channels)  # noqa: SLF001 - this module's
    f = device._fetcher  # noqa: SLF001 - this module's
    held = partial(device._read_held, r, skipped) if decode else partial(f.fetch, r)  # noqa: SLF001
    return f.prepared(r, held, then(r.fetched), fast=not skipped or not decode, decode=decode)
