"""A bus's poller: one thread per bus that runs the schedule
(:mod:`pymb.logger.schedule`) over its devices, reconnects with a backoff,
and hands samples and events to the writer (:class:`~pymb.logger.report.Report`)."""

from __future__ import annotations

import functools
import queue
import threading
import time
from array import array
from collections.abc import Callable
from dataclasses import dataclass

from pymb.client import unresolved
from pymb.devices.deviceconfig import DeviceConfig
from pymb.devices.hubsweep import SweepReader
from pymb.devices.identify import client_asker, identify, mismatch
from pymb.devices.mapdevice import MapDevice, prepared_read
from pymb.devices.mapreading import GroupDecode, MapReading
from pymb.errors import DeviceFailure, ModbusConnectionError, ModbusError
from pymb.logger.config import BusConfig
from pymb.logger.report import Report
from pymb.logger.schedule import BACKOFF_MAX, TEXT, Agenda, Backoff, Health, Slot, reappeared
from pymb.logger.stats import Stats
from pymb.maps import Decoder
from pymb.store import DeviceInfo, Event, Sample
from pymb.store.block import PollBlock, PollSource
from pymb.wire import registers_to_wire

__all__ = ["BusPoller", "MapHealth", "Stats", "map_info"]

_NONE: frozenset[int] = frozenset()


@dataclass(eq=False)
class MapHealth:
    """A device being polled (its MapDevice: write commands use it) and
    how its polling goes."""

    info: DeviceInfo
    config: DeviceConfig
    device: MapDevice
    health: Health
    explained: str = ""  #: what answered a device of no value, found once per run of failures

    @property
    def offline(self) -> bool:
        """Whether the device is left alone after failed polls."""
        return self.health.offline


@dataclass(eq=False)
class _Read:
    """A slot of the schedule and what reading it takes: a group of a map
    device (``group``: its registers go to the writer as they are), or a
    hub's sweep (``read``: a :class:`MapReading`)."""

    slot: Slot
    dev: MapHealth
    read: Callable[[], MapReading] | None = None
    group: _GroupRead | None = None
    backoff: bool = False  #: the map's ``[device.timing] backoff``


class _GroupRead:
    """A map device's group read as the logger keeps it, like the TCP loop's
    polls: the registers fetched and nothing decoded (the writer stores the
    registers; :meth:`MapDevice.read_group` decodes every value and state
    into dicts, about 35 µs a CoolPro sample; a hub's sweep, 700 values and
    states into arrays), handed over as a poll of :attr:`source`
    (:meth:`Report.poll <pymb.logger.report.Report.poll>`), with the points
    the planner holds refused ``unsupported``. ``busy``: what a device
    failure raises instead (a hub's: busy through every retry)."""

    __slots__ = ("busy", "dev", "how", "read", "source")

    def __init__(self, info: DeviceInfo, dev: MapDevice, group: str | None,
                 busy: Callable[[DeviceFailure], ModbusError] | None = None) -> None:
        self.dev = dev
        self.how = GroupDecode(dev.map, group)
        self.source = PollSource(info, self.how)
        self.busy = busy
        #: the fetch made ready (one C call while nothing changes), giving the image
        self.read = prepared_read(dev, _image, group=group, decode=False)

    def __call__(self) -> tuple[bytes, frozenset[int]]:
        """One read: the registers (big-endian, the group's layout) and the
        items of the group the device refused."""
        try:
            image = self.read()
        except DeviceFailure as e:
            if self.busy is None:
                raise
            raise self.busy(e) from None
        unread = self.dev.planner.unsupported
        if unread:
            unread &= self.how.items
        return image, unread


def _image(fetched: tuple[tuple[Decoder, array[int]], ...]) -> Callable[[], bytes]:
    """The group's image of the registers a read fetched (big-endian, table
    after table), taken while the read holds the line."""
    if len(fetched) == 1:
        return functools.partial(registers_to_wire, fetched[0][1])
    arrays = [regs for _, regs in fetched]
    return lambda: b"".join([registers_to_wire(regs) for regs in arrays])


def map_info(bus: BusConfig, d: DeviceConfig) -> DeviceInfo:
    """The record a device's samples and events carry: its map text, options
    and deadbands, and the options a device of channels has (``channels``,
    ``humidity_unit``: one, or one a channel) as its fields."""
    assert d.address is not None
    opts = d.map.options
    unit = d.option("humidity_unit") if "humidity_unit" in opts else 0.1
    return DeviceInfo(bus.name, bus.endpoint, d.type, d.address, d.name,
                      int(opts.get("channels", 0)),
                      tuple(float(u) for u in unit) if isinstance(unit, tuple) else float(unit),
                      map_source=d.text.text,
                      map_options=tuple((k, float(v)) for k, v in sorted(d.options.items())
                                        if not isinstance(v, tuple)),
                      map_deadband=tuple(sorted(d.deadband.items())))


class BusPoller(threading.Thread):
    """Polls one bus until told to stop; puts Samples and Events on a queue.
    ``decoded``: a hub's sweeps go as :class:`SweepReader` decodes them (its
    arrays, which ``--on-change`` compares), not as their registers."""

    def __init__(self, bus: BusConfig, out: queue.Queue[list[Sample | Event | PollBlock]],
                 stop: threading.Event,
                 stats: Stats, clock: Callable[[], float] = time.monotonic, *,
                 decoded: bool = False) -> None:
        super().__init__(name=f"pymb-bus-{bus.name}", daemon=True)
        self.bus = bus
        self.decoded = decoded
        self.report = Report(out, stats)
        self.stop_event = stop
        self.stats = stats
        self.clock = clock
        self.client = bus.client()
        self.devices = [(map_info(bus, d), d) for d in bus.devices]
        #: device name -> its MapDevice and health, once polling started
        self.healths: dict[str, MapHealth] = {}
        stats.opened.setdefault(bus.name, False)

    def flush(self) -> None:
        """Hand what was read since the last list to the writer."""
        self.report.flush()

    def take_unflushed(self) -> list[Sample | Event | PollBlock]:
        """What this poller read but has not handed over (for the writer, once
        the poller is left behind at stop)."""
        return self.report.take()

    def _reads(self) -> list[_Read]:
        """The schedule's slots: each group of each device (at the bus's
        interval for a group of ``poll = "bus"``)."""
        bus = self.bus
        out: list[_Read] = []
        rate = bus.baud if bus.port is not None else None
        for info, cfg in self.devices:
            dev, read = cfg.open(self.client, rate)
            health = Health.of_map(info.name, cfg.offline_after, cfg.offline_retry,
                                   cfg.map.timing.backoff)
            h = self.healths[info.name] = MapHealth(info, cfg, dev, health)
            for group, interval in cfg.polls:
                slot = Slot(health, bus.interval if interval is None else interval,
                            interval == 0, group)
                backoff = cfg.map.timing.backoff
                if isinstance(read, SweepReader) and (read.mixed or self.decoded):
                    out.append(_Read(slot, h, functools.partial(read, group), backoff=backoff))
                else:
                    busy = read.busy if isinstance(read, SweepReader) else None
                    out.append(_Read(slot, h, group=_GroupRead(info, dev, group, busy),
                                     backoff=backoff))
        return out

    def _why_not_open(self, e: ModbusError) -> str:
        host = getattr(self.client, "host", None)
        if host is not None:
            why = unresolved(host)
            if why is not None:
                return f"cannot connect to {self.bus.endpoint}: {why}"
        return str(e)

    def _connect(self) -> bool:
        """Open the bus, retrying with a backoff; False: told to stop first."""
        backoff = Backoff()
        while not self.stop_event.is_set():
            try:
                self.client.connect()
                self.report.opened(self.bus.name)
                return True
            except ModbusError as e:
                wait = backoff.take()
                self.report.not_open(self.bus.name, self._why_not_open(e), wait)
                if self.stop_event.wait(wait):
                    return False
        return False

    def run(self) -> None:
        try:
            self._run()
        finally:
            self.flush()
            self.client.close()

    def _run(self) -> None:
        if not self._connect():
            return
        self.report.connected(self.bus.name, self.bus.endpoint,
                              len(self.devices))
        reads = self._reads()
        clock, stop = self.clock, self.stop_event
        is_set, poll = stop.is_set, self._poll
        agenda: Agenda[_Read] = Agenda()
        start = clock()
        for r in reads:
            r.slot.next_at = start
            agenda.put(r.slot, r, start)
        while not is_set():
            now = clock()
            due = agenda.due(now)
            if not due:
                self.flush()
                if stop.wait(min(max(agenda.next() - now, 0.0), BACKOFF_MAX)):
                    return
                continue
            alone = len(due) == 1
            for r in due:
                if is_set():
                    return
                slot = r.slot
                flat = alone and slot.interval == 0 and not slot.once
                while slot.due(clock()):  # (not if its device failed since, in this round)
                    got = poll(r)
                    if got is False:
                        return
                    late = slot.advance(clock())
                    if late:
                        self.report.skipped(self.bus.name, slot, late)
                    if got is None:  # the bus was opened again: the devices may be new
                        reappeared(x.slot for x in reads)
                        for x in reads:  # (each read once was no longer in the agenda)
                            if x.slot.once and x is not r:
                                agenda.put(x.slot, x, clock())
                    # Read flat out and alone: read again while nothing else is due
                    # (what the agenda would give next), without the agenda.
                    if not flat or is_set() or agenda.next() <= clock():
                        break
                agenda.put(slot, r, slot.wake(clock()))

    def _poll(self, r: _Read) -> bool | None:
        """Read one slot; False when the bus is gone for good (stopping),
        None when it was lost and opened again."""
        report, bus, h, dev = self.report, self.bus, r.slot.health, r.dev
        info = dev.info
        g = r.group
        try:
            if g is not None:
                image, unread = g()
            else:
                assert r.read is not None
                data = r.read()
                unread = _NONE
        except ModbusConnectionError as e:
            report.error(bus.name, h, info, e, self.clock())
            self.client.close()
            if not self._connect():
                return False
            report.reconnected(bus.name, bus.endpoint)
            return None
        except ModbusError as e:
            report.error(bus.name, h, info, e, self.clock())
            return True
        if g is not None:
            refused = g.how.unsupported(unread) if unread else ()
        else:
            refused = data.unsupported
        if r.backoff and refused and len(refused) == (
                len(g.how.names) if g is not None else len(data.values)):
            # Every point "unsupported": the device supplied no value at all.
            # Not a sample: a fault, and the next try probes the points again.
            if not dev.explained:
                dev.explained = self._explain(info)
            dev.device.planner.forget()
            report.failed(bus.name, h, info, "no_value",
                          TEXT["no_value"].format(name=info.name, why=dev.explained), None,
                          self.clock(), at_once=True)
            return True
        if g is not None:
            report.poll(g.source, time.monotonic(), image, unread)
        else:
            report.sample(Sample(info, time.time(), time.monotonic(), data))
        if h.failures or h.offline or refused or h.name in self.stats.problems:
            if r.backoff and h.failures:
                dev.explained = ""
            report.answered(bus.name, h, info, refused)  # (only where that is news)
        return True

    def _explain(self, info: DeviceInfo) -> str:
        try:
            found = identify(client_asker(self.client), info.address)
        except ModbusError as e:
            return str(e)
        return mismatch(found, info.type, info.address, info.channels)
