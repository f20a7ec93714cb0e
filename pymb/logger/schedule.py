"""A bus with map devices: every polling group of every map device at its
own interval (0: once after each (re)connect), the built-in devices at the
bus's interval, and each map device's health: after ``offline_after``
failed polls in a row it is left alone for ``offline_retry`` seconds and
then tried with one request, so a dead unit costs the live ones on its bus
at most one timeout per retry period."""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol

from pymb.client import Client
from pymb.devices.mapdevice import MapDevice
from pymb.errors import DeviceException, ModbusConnectionError, ModbusError
from pymb.logger.config import BusConfig
from pymb.logger.mapconfig import MapDeviceConfig, failed_poll
from pymb.logger.stats import Stats
from pymb.store import DeviceInfo, Sample
from pymb.store.records import event_kind, short_fault

__all__ = ["Builtin", "Bus", "MapHealth", "Slot", "run_scheduled", "slots_of"]


@dataclass(eq=False)
class MapHealth:
    """A map device being polled and how its polling goes."""

    info: DeviceInfo
    config: MapDeviceConfig
    device: MapDevice
    failures: int = 0  #: failed polls in a row
    retry_at: float = 0.0  #: offline: not polled before this (clock)
    offline: bool = False



class Builtin(Protocol):
    """A built-in device on the bus, as the schedule sees it."""

    retry_at: float  #: not polled before this (clock)


class Bus(Protocol):
    """The poller of a bus as the schedule uses it
    (:class:`pymb.logger.poller.BusPoller`)."""

    bus: BusConfig
    client: Client
    clock: Callable[[], float]
    stop_event: threading.Event
    stats: Stats
    healths: dict[str, MapHealth]

    def flush(self) -> None:
        """Hand what was read to the writer."""
        ...

    def connect(self) -> bool:
        """(Re)open the bus; False when it is gone for good."""
        ...

    def event(self, kind: str, message: str, device: DeviceInfo | None = None,
              code: int | None = None) -> None:
        """Record an event."""
        ...

    def add_sample(self, sample: Sample) -> None:
        """Queue a sample for the writer."""
        ...

    def stamp(self) -> tuple[float, float]:
        """(wall, monotonic) time of a read that just ended."""
        ...


@dataclass(eq=False)
class Slot:
    """One thing read on a schedule: a map device's group, or a built-in device."""

    interval: float  #: seconds; 0: once per connection (``once``) or flat out
    once: bool = False  #: a map group of interval 0: read once after each (re)connect
    group: str | None = None
    map: MapHealth | None = None
    builtin: Builtin | None = None
    poll: Callable[[], bool] | None = None  #: a built-in device's read (False: bus gone)
    next_at: float = 0.0
    read_once: bool = False  #: an interval-0 group read on this connection

    def due(self, now: float) -> bool:
        """Whether this slot is to be read at ``now``."""
        if self.map is not None:
            if self.map.offline and now < self.map.retry_at:
                return False
            if self.once:
                return not self.read_once
        elif self.builtin is not None and self.builtin.retry_at > now:
            return False
        return self.interval == 0 or now >= self.next_at

    def wake(self, now: float) -> float:
        """When this slot is due next (inf: not before a reconnect)."""
        if self.map is not None and self.map.offline:
            return max(self.map.retry_at, self.next_at if self.interval else self.map.retry_at)
        if self.map is not None and self.once:
            return math.inf if self.read_once else now
        if self.builtin is not None:
            return max(self.builtin.retry_at, self.next_at)
        return self.next_at


def slots_of(poller: Bus, maps: list[tuple[DeviceInfo, MapDeviceConfig]],
             builtins: Sequence[tuple[Builtin, Callable[[], bool]]] = ()) -> list[Slot]:
    """The slots of a bus: each group of each map device, each built-in device."""
    out: list[Slot] = []
    rate = poller.bus.baud if poller.bus.port is not None else None
    for info, cfg in maps:
        dev = MapDevice(poller.client, cfg.map, cfg.address, baudrate=rate)
        health = MapHealth(info, cfg, dev)
        poller.healths[info.name] = health  # for write commands
        for group, interval in cfg.polls:
            out.append(Slot(poller.bus.interval if interval is None else interval,
                            interval == 0, group, health))
    out += [Slot(poller.bus.interval, builtin=d, poll=read) for d, read in builtins]
    return out


def run_scheduled(poller: Bus, slots: list[Slot]) -> None:
    """Poll ``slots`` until told to stop (the poller is connected)."""
    clock, stop = poller.clock, poller.stop_event
    start = clock()
    for s in slots:
        s.next_at = start
    while not stop.is_set():
        now = clock()
        due = [s for s in slots if s.due(now)]
        if not due:
            wake = min(s.wake(now) for s in slots)
            poller.flush()
            if stop.wait(min(max(wake - now, 0.0), 30.0)):
                return
            continue
        for s in due:
            if stop.is_set():
                return
            if not (s.poll() if s.poll is not None else _poll_map(poller, s, slots)):
                return
            _advance(poller, s)


def _advance(poller: Bus, s: Slot) -> None:
    """The slot's next time; whole slots a long read overran are skipped and counted."""
    if s.once:
        s.read_once = True
        return
    if s.interval == 0:
        return
    s.next_at += s.interval
    now = poller.clock()
    if now > s.next_at:
        late = int((now - s.next_at) / s.interval) + 1
        s.next_at += late * s.interval
        poller.stats.skipped(late)
        what = f"{s.map.info.name} group {s.group}" if s.map is not None and s.group else \
            "a device"
        poller.event("skipped", f"{late} poll slot(s) of {s.interval:g} s skipped ({what})")


def _poll_map(poller: Bus, s: Slot, slots: list[Slot]) -> bool:
    """Read one group of a map device; False when the bus is gone for good."""
    h = s.map
    assert h is not None
    name = h.info.name
    try:
        reading = h.device.read_group(s.group)
    except ModbusConnectionError as e:
        _failed(poller, h, event_kind(e), str(e), getattr(e, "errno", None))
        poller.client.close()
        if not poller.connect():
            return False
        for other in slots:
            other.read_once = False
        poller.event("reconnect", f"reconnected to {poller.bus.endpoint}")
        return True
    except ModbusError as e:
        code = getattr(e, "code", None) if isinstance(e, DeviceException) else \
            getattr(e, "errno", None)
        _failed(poller, h, event_kind(e), str(e), code)
        return True
    poller.add_sample(Sample(h.info, *poller.stamp(), reading))
    if reading.unsupported:
        poller.stats.refused(name, reading.unsupported)
    if h.offline:
        poller.event("online", f"{name} answers again", h.info)
    h.failures, h.offline = 0, False
    poller.stats.ok(name)
    return True


def _failed(poller: Bus, h: MapHealth, kind: str, message: str, code: int | None) -> None:
    retry = failed_poll(h, poller.clock())
    stats = poller.stats
    stats.count(stats.device_faults, h.info.name, 1)
    stats.fault(h.info.name, f"{h.info.name}: {short_fault(kind, message)}")
    poller.event(kind, message + retry, h.info, code)
