"""What the one-loop TCP poller (:mod:`pymb.logger.tcploop`) keeps per map
device and per polling group: :class:`Unit` (a map device at a unit id: its
planner, timing and health) and :class:`Entry` (one group of a unit: its
schedule, its prepared requests, its sample image and its
:class:`~pymb.store.block.PollSource`, which names its polls to the writer:
the device, and the group's :class:`~pymb.devices.mapreading.GroupDecode`,
which decodes the registers only when someone asks for the values; the
SQLite writer stores the registers and never does).

An entry's image is laid out as the store keeps a map reading
(:func:`pymb.devices.mapreading.group_layout`): each table's registers, from
its first point's to its last's, big-endian, one table after the other (a
bit as a 0/1 word). A reply's data bytes go to their place in it in one
slice assignment; a poll's sample is that image, copied once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from pymb._native.master import DROPPED, MasterRead, PollTable
from pymb.devices.deviceconfig import DeviceConfig
from pymb.devices.mapreading import GroupDecode
from pymb.errors import ModbusError, request_error, request_text
from pymb.logger.schedule import Health, Slot
from pymb.maps.device_plan import MapItems, PointPlanner, map_planner
from pymb.maps.planner import Line, ReadPlan, Request
from pymb.store import DeviceInfo
from pymb.store.block import PollSource
from pymb.wire import DEFAULT_BAUD, bits_per_char

__all__ = ["Entry", "PollRequest", "Unit", "asked", "request_failed"]

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


@dataclass(eq=False)
class Entry:
    """One polling group of a unit: its slot of the schedule and its requests."""

    unit: Unit
    slot: Slot
    decode: GroupDecode
    wanted: tuple[int, ...]  #: the planner items of the group (the same tuple each poll)
    source: PollSource  #: its polls' device and decoder, as the writer takes them
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
    id: int = -1  #: its polls' name to the loop's C part (:attr:`pymb._native.loop.Loop.done`)

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
                   PollSource(unit.info, how),
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

    def carriable(self, now: float) -> bool:
        """Whether a poll of this group may be one of a chain the loop's C part
        carries: read on a schedule (not flat out, not once), due at ``now``,
        its device not timed, no refused point due to be asked again."""
        slot, u = self.slot, self.unit
        return (slot.interval > 0 and not slot.once and not u.timed and slot.due(now)
                and u.planner.retry_at == math.inf)

    def unsupported(self) -> frozenset[int]:
        """The group's items the unit's planner leaves out for now (taken
        again only when the planner changed)."""
        p = self.unit.planner
        if p.version != self._seen:
            self._unread, self._seen = p.unsupported & self.decode.items, p.version
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


def asked(spec: PollRequest | None, u: Unit) -> str:
    """The request as errors name it: ``read_input_registers(slave=1, address=0, count=4)``
    (no request: the device's name)."""
    if spec is None:
        return request_text(0, u.info.address, context=u.info.name)
    return request_text(spec.function, u.info.address, spec.address, spec.count)


def request_failed(err: int, endpoint: str, spec: PollRequest, u: Unit,
                   got: bytes | None = None, dropped: bytes = b"") -> ModbusError:
    """The error of request ``spec`` of ``u`` at ``endpoint`` that failed
    with ``err``, as a client's request says it (``got``: what came of its
    reply; else ``dropped``: a reply under another transaction id, dropped)."""
    other = bool(dropped) and not got
    return request_error(err, function=spec.function, slave=u.info.address,
                         address=spec.address, count=spec.count, port=endpoint,
                         timeout=u.timeout, failed=(spec.address, spec.count),
                         response=dropped if other else got, header=7,
                         frame=DROPPED if other else None, dropped=other)
