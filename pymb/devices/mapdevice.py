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
from collections.abc import Mapping, Sequence
from typing import Any

from pymb.client import Client
from pymb.devices.mapfetch import Fetcher, Image, Read
from pymb.devices.mapreading import MapReading
from pymb.errors import InvalidArgument
from pymb.maps import Decoder, Map, Point, Value
from pymb.maps.device_plan import map_planner
from pymb.maps.model import check_group, did_you_mean
from pymb.maps.planner import Line, ReadPlan
from pymb.maps.types import STATES
from pymb.wire import DEFAULT_BAUD, bits_per_char

__all__ = ["MapDevice"]

#: The line speed a plan is priced at when the client has none (TCP).
DEFAULT_BAUDRATE = DEFAULT_BAUD
_CACHED = 64  #: selections (and their buffers) kept per device


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
        self._selections: dict[tuple[tuple[str, ...], str | None], tuple[int, ...]] = {}
        self._reads: dict[tuple[int, ...], Read] = {}  # per selection (points)
        #: the last read's names, group and Read: a poller asking the same again finds it
        self._last: tuple[tuple[str, ...], str | None, Read] | None = None
        self._fetcher = Fetcher(client, m, address, self._planner)
        # The line's lock, for each whole read and write: a device's requests
        # and the silences between them are never interleaved with another
        # map device's on the same client (and one lock a read, not two).
        self._lock = self._fetcher.quiet.lock
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

    def _read_of(self, names: tuple[str, ...], group: str | None) -> Read:
        """The selection's :class:`Read`, made on its first read: a buffer
        per table, from its first point's register (bit) to its last's, each
        request read in place, and the compiled decoder that walks it in one
        C call."""
        points = self._selection(names, group)
        r = self._reads.get(points)
        if r is None:
            tables: dict[str, list[str]] = {}
            for i in points:
                p = self._points[i]
                tables.setdefault(p.table, []).append(p.name)
            images = {}
            for t, ns in tables.items():
                dec = Decoder(self.map, ns)
                images[t] = Image(dec.address, array("H", bytes(2 * dec.count)), dec)
            r = Read(points, tuple(self._mi.wanted(points)), images)
            if len(self._reads) >= _CACHED:
                self._reads.clear()  # many different selections: keep memory bounded
            self._reads[points] = r
        self._last = (names, group, r)
        return r

    def plan(self, group: str | None = None, *names: str) -> ReadPlan:
        """The requests a read of ``group`` (or of the named points; all by
        default) makes now, with their predicted wire time."""
        return self._planner.plan(tuple(self._mi.wanted(self._selection(names, group))))

    # -- reads ------------------------------------------------------------------------

    def read(self, *names: str, group: str | None = None) -> dict[str, Value]:
        """The named points, or the points of ``group``, or every readable
        point: name -> value (a list for a block; None where there is no
        value, and why in :attr:`states`)."""
        last = self._last
        r = last[2] if last is not None and last[0] == names and last[1] == group else (
            self._read_of(names, group))
        with self._lock:
            self._fetcher.fetch(r)
            return self._decode(r.points, r.images)

    def read_into(self, *names: str, group: str | None = None) -> tuple[Decoder, ...]:
        """Read as :meth:`read` does, but build no dict: the values stay in
        the C decoder's arrays, one :class:`~pymb.maps.Decoder` per table of
        the selection (``d.buffers.values[d.slot(name) + channel - 1]``, its
        state in ``d.buffers.states``; NaN and ``unsupported`` where the
        device refused a point). The same decoders and arrays come back on
        every read of the same selection: a poller's steady state allocates
        nothing for the values."""
        last = self._last
        r = last[2] if last is not None and last[0] == names and last[1] == group else (
            self._read_of(names, group))
        with self._lock:
            self._fetcher.fetch(r)
            for decode, buffers, registers in r.decodes:
                decode()
                buffers.registers = registers
            if self._fetcher.marked:
                self._mark_unread(r.points, r.images)
            return r.decoders

    def _mark_unread(self, points: Sequence[int], images: dict[str, Image]) -> None:
        """In the decoders' arrays: NaN and ``unsupported`` where this read got
        no value."""
        unread, code = self._fetcher.unread, STATES.index("unsupported")
        for i in points:
            p = self._points[i]
            k0 = self._first[i]
            b = images[p.table].decoder.buffers
            slot = images[p.table].decoder.slot(p.name)
            for c in range(p.channels):
                if unread[k0 + c]:
                    b.values[slot + c] = math.nan
                    b.states[slot + c] = code

    def read_group(self, group: str | None = None) -> MapReading:
        """Read ``group`` (every readable point for None) as the logger keeps
        it: a :class:`~pymb.devices.mapreading.MapReading` with the registers
        the requests read (laid out as
        :func:`~pymb.devices.mapreading.group_layout` says), copied."""
        values = self.read(group=group)
        images = self._read_of((), group).images
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
                self._fetcher.after_connect()
                with self._fetcher.turn():
                    current = list(self.client.read_holding_registers(address, p.count,
                                                                      slave=self.address))
        regs = self.map.encode(name, value, current=current)
        with self._lock:
            self._fetcher.after_connect()
            with self._fetcher.turn():
                if p.table == "coil":
                    self.client.write_coil(address, bool(regs[0]), slave=self.address)
                elif len(regs) == 1:
                    self.client.write_register(address, regs[0], slave=self.address)
                else:
                    self.client.write_registers(address, regs, slave=self.address)

    def __repr__(self) -> str:
        return f"<MapDevice {self.map.id}:{self.address} on {self.client.port}>"
