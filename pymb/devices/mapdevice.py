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
import threading
import time
from array import array
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from itertools import groupby
from operator import attrgetter
from typing import Any, NamedTuple

from pymb._native import RegisterPlan
from pymb.client import Client
from pymb.devices.linequiet import quiet_of, sleep_until
from pymb.devices.mapreading import MapReading
from pymb.errors import IllegalDataAddress, IllegalDataValue, InvalidArgument
from pymb.maps import Decoder, Map, Point, Value
from pymb.maps.device_plan import map_planner
from pymb.maps.model import check_group, did_you_mean
from pymb.maps.planner import BIT_TABLES, Line, ReadPlan, Request
from pymb.maps.types import STATES
from pymb.wire import DEFAULT_BAUD, bits_per_char

__all__ = ["MapDevice"]

#: The line speed a plan is priced at when the client has none (TCP).
DEFAULT_BAUDRATE = DEFAULT_BAUD
_CACHED = 64  #: selections (and their buffers) kept per device


class _Image(NamedTuple):
    """One table's registers of a selection: read in place, decoded in C."""

    address: int  #: of its first register
    registers: array[int]
    decoder: Decoder


class _Prepared(NamedTuple):
    """A run of a prepared plan's requests into one table's buffer: one C call."""

    requests: tuple[Request, ...]
    image: _Image
    plan: RegisterPlan  #: the requests as C takes them


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
    """

    def __init__(self, client: Client, m: Map, address: int | None = None, *,
                 options: Mapping[str, object] | None = None,
                 baudrate: int | None = None) -> None:
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
        if options:
            m = m.configure(options)
        dev = m.device
        if address is None:
            address = dev.default_address
        low, high = dev.addresses
        if isinstance(address, bool) or not isinstance(address, int) or not (
                low <= address <= high):
            raise InvalidArgument(f"{m.id} address must be {low}..{high}, got {address!r}")
        self.client = client
        self._quiet = quiet_of(client)  #: the line's silences, shared with its other devices
        self.map = m
        self.address = address
        rate = getattr(client, "baudrate", None) or baudrate or DEFAULT_BAUDRATE
        line = Line(int(rate), bits_per_char(getattr(client, "parity", "N"),
                                              getattr(client, "stop_bits", 1),
                                              getattr(client, "data_bits", 8)))
        self._planner, mi = map_planner(m, line)
        self._mi = mi
        self._points: tuple[Point, ...] = mi.points
        self._first = mi.first
        self._index = {p.name: i for i, p in enumerate(self._points)}
        items = mi.items
        self._selections: dict[tuple[tuple[str, ...], str | None], tuple[int, ...]] = {}
        self._wanted: dict[tuple[int, ...], tuple[int, ...]] = {}  # points -> their items
        # per selection, per table: the first address and the registers
        # (bits) from there to the selection's last, read into in place
        self._images: dict[tuple[int, ...], dict[str, _Image]] = {}
        #: id(plan) -> (plan, its images, its register requests made ready)
        self._ready: dict[int, tuple[ReadPlan, dict[str, _Image],
                                     tuple[_Prepared, ...] | None]] = {}
        self._unread = bytearray(len(items))  # 1: this read got no value for the item
        self._none_unread = bytes(len(items))
        self._lock = threading.Lock()
        self._connections = -1
        self.states: dict[str, Any] = {}  #: the last read's state of each point read

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
        chosen = tuple(dict.fromkeys(out))
        if len(self._selections) >= _CACHED:
            self._selections.clear()  # many different selections: keep memory bounded
        self._selections[key] = chosen
        return chosen

    def _items(self, points: tuple[int, ...]) -> tuple[int, ...]:
        """The planner items of a selection, the same tuple each time."""
        items = self._wanted.get(points)
        if items is None:
            if len(self._wanted) >= _CACHED:
                self._wanted.clear()
            items = self._wanted[points] = tuple(self._mi.wanted(points))
        return items

    def plan(self, group: str | None = None, *names: str) -> ReadPlan:
        """The requests a read of ``group`` (or of the named points; all by
        default) makes now, with their predicted wire time."""
        return self._planner.plan(self._items(self._selection(names, group)))

    # -- reads ------------------------------------------------------------------------

    def read(self, *names: str, group: str | None = None) -> dict[str, Value]:
        """The named points, or the points of ``group``, or every readable
        point: name -> value (a list for a block; None where there is no
        value, and why in :attr:`states`)."""
        points = self._selection(names, group)
        with self._lock:
            images = self._fetch_all(points)
            return self._decode(points, images)

    def read_into(self, *names: str, group: str | None = None) -> tuple[Decoder, ...]:
        """Read as :meth:`read` does, but build no dict: the values stay in
        the C decoder's arrays, one :class:`~pymb.maps.Decoder` per table of
        the selection (``d.buffers.values[d.slot(name) + channel - 1]``, its
        state in ``d.buffers.states``; NaN and ``unsupported`` where the
        device refused a point). The same decoders and arrays come back on
        every read of the same selection: a poller's steady state allocates
        nothing for the values."""
        points = self._selection(names, group)
        with self._lock:
            images = self._fetch_all(points)
            decoders = tuple(image.decoder for image in images.values())
            for image in images.values():
                image.decoder.decode(image.registers)
            if 1 in self._unread:
                self._mark_unread(points, images)
            return decoders

    def _mark_unread(self, points: Sequence[int], images: dict[str, _Image]) -> None:
        """In the decoders' arrays: NaN and ``unsupported`` where this read got
        no value."""
        unread, code = self._unread, STATES.index("unsupported")
        for i in points:
            p = self._points[i]
            k0 = self._first[i]
            b = images[p.table].decoder.buffers
            slot = images[p.table].decoder.slot(p.name)
            for c in range(p.channels):
                if unread[k0 + c]:
                    b.values[slot + c] = math.nan
                    b.states[slot + c] = code

    def _fetch_all(self, points: tuple[int, ...]) -> dict[str, _Image]:
        """The requests of a read of ``points``, each into its place in the
        selection's buffers (the caller holds the lock)."""
        self._prepare()
        plan = self._planner.plan(self._items(points))
        images = self._image(points)
        unread = self._unread
        if 1 in unread:
            unread[:] = self._none_unread
        for r in self._planner.unsupported:
            unread[r] = 1
        self._run(plan, images)
        return images

    def read_group(self, group: str | None = None) -> MapReading:
        """Read ``group`` (every readable point for None) as the logger keeps
        it: a :class:`~pymb.devices.mapreading.MapReading` with the registers
        the requests read (laid out as
        :func:`~pymb.devices.mapreading.group_layout` says), copied."""
        values = self.read(group=group)
        images = self._image(self._selection((), group))
        regs = array("H")
        for image in images.values():
            regs.extend(image.registers)
        gone = tuple(n for n, s in self.states.items()
                     if s == "unsupported" or (isinstance(s, list) and "unsupported" in s))
        return MapReading(self.map, group, values, dict(self.states), regs, gone)

    def _image(self, points: tuple[int, ...]) -> dict[str, _Image]:
        """The buffers of a selection, one per table, made once: the
        registers (bits) from its first point's to its last's, each request
        read in place, and the compiled decoder that walks them in one C call."""
        images = self._images.get(points)
        if images is None:
            names: dict[str, list[str]] = {}
            for i in points:
                p = self._points[i]
                names.setdefault(p.table, []).append(p.name)
            images = {}
            for t, ns in names.items():
                dec = Decoder(self.map, ns)
                images[t] = _Image(dec.address, array("H", bytes(2 * dec.count)), dec)
            if len(self._images) >= _CACHED:
                self._images.clear()
            self._images[points] = images
        return images

    def _prepare(self) -> None:
        """Before a read: reconnect if the line was lost, and after a new
        connection wait ``after_connect`` and forget what the last device taught."""
        client = self.client
        opened = client.ensure_connected()
        if opened or client.connections != self._connections:
            self._connections = client.connections
            self._planner.forget()
            wait = self.map.timing.after_connect
            if wait > 0:
                q = self._quiet
                with q.lock:
                    q.quiet_until = max(q.quiet_until, time.monotonic() + wait)

    def _run(self, plan: ReadPlan, images: dict[str, _Image]) -> None:
        prepared = self._prepared(plan, images)
        if prepared is not None:
            self._run_prepared(prepared)  # its RegisterPlans carry the map's reply timeout
            return
        with self._map_timeout():
            for r in plan.requests:
                self._fetch(r, images[r.table])

    @contextmanager
    def _map_timeout(self) -> Iterator[None]:
        """The map's ``response_timeout`` on the line (the byte timeout stays)."""
        timeout, client = self.map.timing.response_timeout, self.client
        if timeout is None or timeout == client.timeout:
            yield
            return
        before = client.swap_response_timeout_prepared(timeout)
        try:
            yield
        finally:
            client.swap_response_timeout_prepared(before)

    def _prepared(self, plan: ReadPlan, images: dict[str, _Image]
                  ) -> tuple[_Prepared, ...] | None:
        """A plan of register reads only, made ready once: its requests in runs
        of one table, each a RegisterPlan over that table's buffer (None: a
        plan with bits, read request by request)."""
        got = self._ready.get(id(plan))  # the entry holds plan and images: ids stay theirs
        if got is not None and got[0] is plan and got[1] is images:
            return got[2]
        ready: tuple[_Prepared, ...] | None = None
        if not any(r.table in BIT_TABLES for r in plan.requests):
            t = self.map.timing
            gap = max(t.inter_request_gap, t.turnaround)
            runs = [tuple(g) for _, g in groupby(plan.requests, key=attrgetter("table"))]
            ready = tuple(
                _Prepared(rs, image, RegisterPlan(
                    [(r.function, self.address, r.address, r.count, r.address - image.address)
                     for r in rs], image.registers, gap, t.response_timeout))
                for rs in runs for image in (images[rs[0].table],))
        if len(self._ready) >= _CACHED:
            self._ready.clear()
        self._ready[id(plan)] = (plan, images, ready)
        return ready

    def _run_prepared(self, prepared: tuple[_Prepared, ...]) -> None:
        """A prepared plan, a C call per run holding the line (silences as
        :meth:`_turn` keeps them); on exception 02/03 as :meth:`_fetch`."""
        gap, turnaround = self.map.timing.inter_request_gap, self.map.timing.turnaround
        q = self._quiet
        run = self.client.run_read_plan
        monotonic = time.monotonic
        for p in prepared:
            start, n, refused = 0, p.plan.n, -1
            while start < n:
                with q.lock:
                    until = q.quiet_until
                    if q.last_end + gap > until:
                        until = q.last_end + gap
                    if until > monotonic():
                        sleep_until(until)
                    try:
                        run(p.plan, start)
                        start, refused = n, -1
                    except (IllegalDataAddress, IllegalDataValue):
                        if not self._planner.limits.split_on_exception:
                            raise
                        refused = p.plan.failed
                    finally:
                        now = monotonic()
                        q.last_end = now
                        if now + turnaround > q.quiet_until:
                            q.quiet_until = now + turnaround
                if refused >= 0:
                    with self._map_timeout():
                        self._fall_back(p.requests[refused], p.image)
                    start = refused + 1

    @contextmanager
    def _turn(self) -> Iterator[None]:
        """One request's turn on the line: the device's silence before it
        (``inter_request_gap``, and any device's ``turnaround`` after its
        reply), the line held for it, and the end noted for the next."""
        t = self.map.timing
        q = self._quiet
        with q.lock:
            sleep_until(max(q.quiet_until, q.last_end + t.inter_request_gap))
            try:
                yield
            finally:
                now = time.monotonic()
                q.last_end = now
                q.quiet_until = max(q.quiet_until, now + t.turnaround)

    def _wire(self, r: Request, image: _Image) -> None:
        """One request on the wire, into its place in ``image``."""
        buf = image.registers
        at = r.address - image.address
        with self._turn():
            if r.table in BIT_TABLES:
                read = (self.client.read_coils if r.table == "coil"
                        else self.client.read_discrete_inputs)
                bits = read(r.address, r.count, slave=self.address)
                buf[at:at + r.count] = array("H", bits)
            else:
                view = memoryview(buf)[at:at + r.count]
                self.client.read_registers_prepared(r.function, self.address, r.address, view)

    def _fetch(self, r: Request, image: _Image) -> None:
        """Read ``r`` into ``image``; on exception 02/03, fall back as the
        module says, within this read."""
        try:
            self._wire(r, image)
            return
        except (IllegalDataAddress, IllegalDataValue):
            if not self._planner.limits.split_on_exception:
                raise
        self._fall_back(r, image)

    def _fall_back(self, r: Request, image: _Image) -> None:
        """``r`` was refused with exception 02/03: re-plan without the bridge,
        read the extents apart, or mark its points unsupported."""
        planner = self._planner
        if r.bridged and planner.refuse_bridge(r):
            for sub in planner.replan(r).requests:
                self._fetch(sub, image)
        elif len(r.extents) > 1:
            items = planner.items
            for ext in r.extents:
                start = min(items[k].address for k in ext)
                end = max(items[k].end for k in ext)
                self._fetch(Request(r.table, start, end - start, ext, (ext,), 0), image)
        else:
            planner.mark_unsupported(r.items)
            for k in r.items:
                self._unread[k] = 1

    def _decode(self, points: Sequence[int], images: dict[str, _Image]) -> dict[str, Value]:
        """Every table's registers decoded in one C call each; points the
        device refused read None (``unsupported``)."""
        values: dict[str, Value] = {}
        states: dict[str, Any] = {}
        for image in images.values():
            dec = image.decoder
            b = dec.decode(image.registers)
            values.update(dec.values(b))
            states.update(dec.states(b))
        if 1 in self._unread:
            unread = self._unread
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

    def write(self, name: str, value: object, *, channel: int | None = None) -> None:
        """Write ``value`` to a writable point (one ``channel`` of a block).
        The value is checked against the point (access, ``valid``, its
        type's range, ``values``) before any byte is sent; a ``bit``/``bits``
        view reads its register first and writes it back changed."""
        p = self.map.point(name)
        address = p.address
        if p.block:
            if channel is None:
                raise InvalidArgument(f"{self.map.id}: {name!r} is a block: write one channel "
                                      f"(channel=1..{p.channels})")
            address = p.address_of(channel)
        elif channel is not None:
            raise InvalidArgument(f"{self.map.id}: {name!r} has no channels")
        current = None
        if p.writable and p.type in ("bit", "bits", "u8_hi", "u8_lo", "i8_hi", "i8_lo"):
            m = self.map
            m.encode(name, value, current=[0] * p.count)  # refused before any byte is sent
            with self._lock:
                self._prepare()
                with self._turn():
                    current = list(self.client.read_holding_registers(address, p.count,
                                                                      slave=self.address))
        regs = self.map.encode(name, value, current=current)
        with self._lock:
            self._prepare()
            with self._turn():
                if p.table == "coil":
                    self.client.write_coil(address, bool(regs[0]), slave=self.address)
                elif len(regs) == 1:
                    self.client.write_register(address, regs[0], slave=self.address)
                else:
                    self.client.write_registers(address, regs, slave=self.address)

    def __repr__(self) -> str:
        return f"<MapDevice {self.map.id}:{self.address} on {self.client.port}>"
