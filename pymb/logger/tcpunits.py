"""What the one-loop TCP poller (:mod:`pymb.logger.tcploop`) keeps per map
device and per polling group: :class:`Unit` (a map device at a unit id: its
planner, timing and health), :class:`Entry` (one group of a unit: its
schedule, its prepared requests and its sample image) and
:class:`~pymb.devices.mapreading.GroupDecode` (the group's registers
decoded only when someone asks for the values: the SQLite writer stores the
registers and never does).

An entry's image is laid out as the store keeps a map reading
(:func:`pymb.devices.mapreading.group_layout`): each table's registers, from
its first point's to its last's, big-endian, one table after the other (a
bit as a 0/1 word). A reply's data bytes go to their place in it in one
slice assignment; a poll's sample is that image, copied once.
"""

from __future__ import annotations

import sys
from abc import abstractmethod
from array import array
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field, fields
from typing import Any

from pymb._native.master import MasterRead, PollTable
from pymb.devices.deviceconfig import DeviceConfig
from pymb.devices.mapreading import GroupDecode, MapReading
from pymb.logger.schedule import Health, Slot
from pymb.maps import Value
from pymb.maps.device_plan import MapItems, PointPlanner, map_planner
from pymb.maps.planner import Line, ReadPlan, Request
from pymb.store import DeviceInfo, Sample
from pymb.wire import DEFAULT_BAUD, bits_per_char

__all__ = ["Entry", "PollRequest", "Unit", "poll_sample"]

#: the line a TCP client's plans are priced at (as MapDevice prices them)
TCP_LINE = Line(DEFAULT_BAUD, bits_per_char("N", 1, 8))


@dataclass(eq=False)
class Unit:
    """A map device on a TCP bus and how its polling goes."""

    info: DeviceInfo
    config: DeviceConfig
    planner: PointPlanner
    items: MapItems
    timeout: float  #: seconds a request waits for its reply
    gap: float  #: silence before each request (``inter_request_gap``)
    turnaround: float  #: silence after its reply
    health: Health  #: its polls' failures and offline time
    #: whether the device needs silences around its requests (no pipelining)
    timed: bool = field(init=False)

    def __post_init__(self) -> None:
        self.timed = self.gap > 0 or self.turnaround > 0

    @classmethod
    def of(cls, info: DeviceInfo, cfg: DeviceConfig, bus_timeout: float,
           shared: dict[int, tuple[PointPlanner, MapItems]]) -> Unit:
        """The unit of a configured map device (its planner as MapDevice's;
        the map's items ``shared`` by the devices of one map)."""
        m = cfg.map
        got = shared.get(id(m))
        if got is None:
            planner, mi = shared[id(m)] = map_planner(m, TCP_LINE)
        else:
            first, mi = got
            planner = PointPlanner(mi.items, first.limits, first.line,
                                   offline_retry=first.offline_retry, ties=first.ties)
        t = m.timing
        return cls(info, cfg, planner, mi, t.response_timeout or bus_timeout,
                   t.inter_request_gap, t.turnaround,
                   Health.of_map(info.name, cfg.offline_after, cfg.offline_retry))


class PollRequest(MasterRead):
    """One request of a poll, made ready: the planner's request and where
    its data go in the image (the C master frames it, checks its reply and
    copies the data: :class:`pymb._native.master.PollTable`)."""

    __slots__ = ("request",)

    def __init__(self, r: Request, offset: int) -> None:
        super().__init__(r.function, r.address, r.count, offset)
        self.request = r


class _View(Mapping[str, Any]):
    """A sample's values or states, decoded when first read."""

    __slots__ = ()

    @abstractmethod
    def _map(self) -> dict[str, Any]:
        """The decoded dict this view shows."""

    def __getitem__(self, key: str) -> Any:
        return self._map()[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._map())

    def __len__(self) -> int:
        return len(self._map())

    def __repr__(self) -> str:
        return repr(self._map())


class _Values(_View):
    """A sample's values; it decodes them with their states on first use.
    Made by :func:`poll_sample`, which fills in its slots: the group's
    decoder, its registers, the items not read, and what was decoded
    (None until then)."""

    __slots__ = ("got", "how", "regs", "unread")
    how: GroupDecode
    regs: array[int]
    unread: frozenset[int]
    got: tuple[dict[str, Value], dict[str, Any]] | None

    def decoded(self, which: int) -> dict[str, Any]:
        """The values (0) or the states (1)."""
        got = self.got
        if got is None:
            got = self.got = self.how.decode(self.regs, self.unread)
        return got[which]

    def _map(self) -> dict[str, Any]:
        return self.decoded(0)


class _States(_View):
    """A sample's states, decoded with its values (``source``; the states
    point at the values, not back: a poll's records are freed by their
    reference counts, not by the garbage collector)."""

    __slots__ = ("source",)
    source: _Values

    def _map(self) -> dict[str, Any]:
        return self.source.decoded(1)


class _ReadingFill:
    """A poll's :class:`MapReading` while :func:`poll_sample` fills it in
    (then it is made one: the same layout, an instance dict)."""

    map: Any
    group: str | None
    values: _Values
    states: _States
    registers: array[int]
    unsupported: tuple[str, ...]
    wire: bytes


class _SampleFill:
    """A poll's :class:`Sample` while :func:`poll_sample` fills it in."""

    device: DeviceInfo
    time_utc: float
    monotonic: float
    data: MapReading


_SWAP = sys.byteorder == "little"
_NONE: frozenset[int] = frozenset()
_new = object.__new__


def poll_sample(info: DeviceInfo, time_utc: float, monotonic: float, how: GroupDecode,
                image: bytes, unread: frozenset[int] = _NONE) -> tuple[Sample, MapReading]:
    """The :class:`Sample` of one poll of ``info`` and its data: a
    :class:`MapReading` of the registers of ``image`` (big-endian, as on the
    wire), values and states decoded on first use.

    A logger makes these records a poll: each is filled in as a plain
    object, then made what it is (``__class__``: the same layout), where
    their own constructors would each cost a Python call and an instance
    dict made at once (about 1,000 instructions a record more, callgrind);
    the views' slots are filled in from here too."""
    regs = array("H", image)
    if _SWAP:
        regs.byteswap()
    values: _Values = _new(_Values)
    values.how = how
    values.regs = regs
    values.unread = unread
    values.got = None
    states: _States = _new(_States)
    states.source = values
    r: Any = _new(_ReadingFill)
    r.map = how.map
    r.group = how.group
    r.values = values
    r.states = states
    r.registers = regs
    r.unsupported = how.unsupported(unread) if unread else ()
    r.wire = image
    r.__class__ = MapReading
    s: Any = _new(_SampleFill)
    s.device = info
    s.time_utc = time_utc
    s.monotonic = monotonic
    s.data = r
    s.__class__ = Sample
    return s, r


def _check_fills() -> None:
    """Each fill sets exactly its record's fields (checked at import: a
    field added to a record and not here fails at once, not at its first use)."""
    for fill, record in ((_ReadingFill, MapReading), (_SampleFill, Sample)):
        want = [f.name for f in fields(record)]
        if list(fill.__annotations__) != want:
            raise AssertionError(f"{fill.__name__} fills {list(fill.__annotations__)}, "
                                 f"{record.__name__} has {want}")


_check_fills()


@dataclass(eq=False)
class Entry:
    """One polling group of a unit: its slot of the schedule and its requests."""

    unit: Unit
    slot: Slot
    decode: GroupDecode
    wanted: tuple[int, ...]  #: the planner items of the group (the same tuple each poll)
    queued: bool = False  #: waiting in its connection's queue
    plan: ReadPlan | None = None
    specs: list[PollRequest] = field(default_factory=list)
    image: bytearray = field(default_factory=bytearray)
    #: :attr:`specs` made ready for the C master
    table: PollTable | None = None
    #: the planner's version at the last :meth:`requests`: while it is the
    #: same and no refused point is due to be asked again, so is the plan
    version: int = -1
    #: the planner's unsupported items as of its version ``_seen``
    _unread: frozenset[int] = frozenset()
    _seen: int = -1

    @classmethod
    def of(cls, unit: Unit, group: str | None, interval: float, once: bool,
           shared: dict[tuple[int, str | None], GroupDecode]) -> Entry:
        """The entry of ``unit``'s ``group`` (its decoders ``shared`` by the
        devices of one map)."""
        m = unit.config.map
        how = shared.get((id(m), group))
        if how is None:
            how = shared[id(m), group] = GroupDecode(m, group, unit.items)
        wanted = tuple(sorted(how.items))
        return cls(unit, Slot(unit.health, interval, once, group), how, wanted,
                   image=bytearray(2 * sum(d.count for d in how.decoders)))

    def requests(self) -> list[PollRequest]:
        """This poll's requests as the planner plans them now (made ready
        again only when the plan changed: a refused bridge or point). The
        list is this entry's: not to be changed."""
        planner = self.unit.planner
        plan = planner.plan(self.wanted)
        self.version = planner.version
        if plan is not self.plan:
            lay = self.decode.layout()
            self.specs = [self.spec(r, lay) for r in plan.requests]
            self.table = self.table_of(self.specs)
            self.plan = plan
        return self.specs

    def unsupported(self) -> frozenset[int]:
        """The items the unit's planner leaves out for now (taken again only
        when the planner changed)."""
        p = self.unit.planner
        if p.version != self._seen:
            self._unread, self._seen = p.unsupported, p.version
        return self._unread

    def table_of(self, specs: list[PollRequest]) -> PollTable:
        """``specs`` (this group's) made ready for the C master."""
        return PollTable(specs, self.unit.info.address, self.image)

    def spec(self, r: Request, lay: dict[str, tuple[int, int, int]] | None = None) -> PollRequest:
        """A request of this group made ready."""
        first, count, off = (lay or self.decode.layout())[r.table]
        if not first <= r.address <= r.address + r.count <= first + count:
            raise ValueError(f"{r.table} {r.address}+{r.count} outside the group's "
                             f"registers {first}+{count}")
        return PollRequest(r, off + 2 * (r.address - first))
