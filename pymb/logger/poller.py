"""A bus's poller: one thread per bus that reads its devices on schedule,
reconnects with a backoff, and hands samples and events to the writer."""

from __future__ import annotations

import collections
import functools
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from pymb.client import unresolved
from pymb.devices import CoolPro, HubReading, SensorHub
from pymb.devices.hub import ALL_BLOCKS
from pymb.devices.identify import client_asker, identify, mismatch
from pymb.devices.spec import DeviceConfig
from pymb.errors import ModbusConnectionError, ModbusError
from pymb.logger.config import BusConfig
from pymb.logger.mapconfig import MapDeviceConfig
from pymb.logger.schedule import MapHealth, run_scheduled, slots_of
from pymb.logger.stats import Stats
from pymb.store import DeviceInfo, Event, Sample
from pymb.store.records import event_kind, short_fault

__all__ = ["BusPoller", "Stats", "map_info"]

_BACKOFF_FIRST, _BACKOFF_MAX = 0.5, 30.0
_FAULTS_BEFORE_BACKOFF = 10  #: consecutive failed reads of a device before it is backed off


@dataclass
class _Device:
    """A device being polled and how its polling goes."""

    info: DeviceInfo
    config: DeviceConfig
    read: Callable[[], Any]
    hub: SensorHub | None
    #: hub readings the writer has finished with, for the next sweeps to read
    #: into (no 8 KB of arrays allocated per sweep, and none freed by another
    #: thread); None: every read makes its own
    spare: collections.deque[HubReading] | None = None
    failures: int = 0  #: consecutive failed reads
    backoff: float = 0.0  #: seconds of the current backoff (0: none)
    retry_at: float = 0.0  #: not polled before this (clock)
    explained: str = ""  #: what answered, found once per run of failures


def map_info(bus: BusConfig, d: MapDeviceConfig) -> DeviceInfo:
    """The record a map device's samples and events carry."""
    return DeviceInfo(bus.name, bus.endpoint, d.type, d.address, d.name,
                      map_source=d.source.text,
                      map_options=tuple((k, float(v)) for k, v in sorted(d.options.items())),
                      map_deadband=tuple(sorted(d.deadband.items())))


def _reading_into(hub: SensorHub, spare: collections.deque[HubReading]) -> Callable[[], Any]:
    """``hub.read_all`` into a spare reading when there is one."""
    def read() -> HubReading:
        return hub.read_all(into=spare.pop() if spare else None)
    return read


#: spare readings kept per hub: the most a writer a batch behind hands back
SPARE_MAX = 64
#: A poller hands its samples to the writer in lists of at most this many, or
#: this old (seconds), and before it waits: one queue operation per list, not
#: two per sample. Events go at once, after the samples before them.
BATCH_MAX = 64
_BATCH_AGE = 0.02


class BusPoller(threading.Thread):
    """Polls one bus until told to stop; puts Samples and Events on a queue."""

    def __init__(self, bus: BusConfig, out: queue.Queue[list[Sample | Event]],
                 stop: threading.Event,
                 stats: Stats, clock: Callable[[], float] = time.monotonic, *,
                 reuse: bool = False) -> None:
        super().__init__(name=f"pymb-bus-{bus.name}", daemon=True)
        self.bus = bus
        self.out = out
        self._batch: list[Sample | Event] = []
        self._batch_since = 0.0
        self.stop_event = stop
        self.stats = stats
        self.clock = clock
        self.client = bus.client()
        self.devices: list[_Device] = []
        self.maps: list[tuple[DeviceInfo, MapDeviceConfig]] = []
        #: map device name -> its MapDevice and health, once polling started
        self.healths: dict[str, MapHealth] = {}
        stats.opened.setdefault(bus.name, False)
        for d in bus.devices:
            assert d.address is not None
            if isinstance(d, MapDeviceConfig):
                self.maps.append((map_info(bus, d), d))
                continue
            units = d.humidity_unit
            info = DeviceInfo(bus.name, bus.endpoint, d.type, d.address, d.name,
                              d.channels if d.type == "hub" else 0,
                              tuple(units) if isinstance(units, list) else units)
            if d.type == "coolpro":
                self.devices.append(_Device(info, d, CoolPro(self.client, d.address)
                                            .read_telemetry, None))
            else:
                hub = SensorHub(self.client, d.address, d.channels, d.humidity_unit)
                if reuse:
                    spare: collections.deque[HubReading] = collections.deque()
                    self.devices.append(_Device(info, d, _reading_into(hub, spare), hub, spare))
                else:
                    self.devices.append(_Device(info, d, hub.read_all, hub))

    def _event(self, kind: str, message: str, device: DeviceInfo | None = None,
               code: int | None = None) -> None:
        self._batch.append(Event(time.time(), time.monotonic(), self.bus.name, device, kind,
                                 code, message))
        self.flush()

    def event(self, kind: str, message: str, device: DeviceInfo | None = None,
              code: int | None = None) -> None:
        """Record an event now (handed over at once)."""
        self._event(kind, message, device, code)

    def stamp(self) -> tuple[float, float]:
        """(UTC, monotonic) time of a sample completed now."""
        return time.time(), time.monotonic()

    def add_sample(self, sample: Sample) -> None:
        """Add a sample to the list for the writer (handed over when full or old)."""
        batch = self._batch
        now = sample.monotonic
        if not batch:
            self._batch_since = now
        batch.append(sample)
        if len(batch) >= BATCH_MAX or now - self._batch_since >= _BATCH_AGE:
            self.flush()

    def connect(self) -> bool:
        """Open the bus, retrying with a backoff; False: told to stop first."""
        return self._connect()

    def poll_device(self, dev: _Device) -> bool:
        """Read one built-in device; False when the bus is gone for good."""
        return self._poll(dev)

    def flush(self) -> None:
        """Hand what was read since the last list to the writer."""
        batch, self._batch = self._batch, []
        if batch:
            self.out.put(batch)

    def take_unflushed(self) -> list[Sample | Event]:
        """What this poller read but has not handed over (for the writer, once
        the poller is left behind at stop)."""
        batch, self._batch = self._batch, []
        return batch

    def _why_not_open(self, e: ModbusError) -> str:
        host = getattr(self.client, "host", None)
        if host is not None:
            why = unresolved(host)
            if why is not None:
                return f"cannot connect to {self.bus.endpoint}: {why}"
        return str(e)

    def _connect(self) -> bool:
        backoff = _BACKOFF_FIRST
        while not self.stop_event.is_set():
            try:
                self.client.connect()
                self.stats.opened[self.bus.name] = True
                self.stats.ok(self.bus.name)
                return True
            except ModbusError as e:
                why = self._why_not_open(e)
                self.stats.fault(self.bus.name, f"bus {self.bus.name}: {why}")
                self._event("connection", f"{why}; retrying in {backoff:g} s")
                if self.stop_event.wait(backoff):
                    return False
                backoff = min(backoff * 2, _BACKOFF_MAX)
        return False

    def run(self) -> None:
        try:
            self._run()
        finally:
            self.flush()
            self.client.close()

    def _wait_for_a_device(self) -> bool:
        """With every device backed off, sleep until the first is due; False: stop."""
        due = min(d.retry_at for d in self.devices)
        delay = due - self.clock()
        return not (delay > 0 and self.stop_event.wait(min(delay, _BACKOFF_MAX)))

    def _run(self) -> None:
        if not self._connect():
            return
        self._event("connect", f"polling {len(self.devices) + len(self.maps)} device(s) on "
                    f"{self.bus.endpoint}")
        if self.maps:
            builtins = [(d, functools.partial(self.poll_device, d)) for d in self.devices]
            run_scheduled(self, slots_of(self, self.maps, builtins))
            return
        interval = self.bus.interval
        start = self.clock()
        slot = 0
        while not self.stop_event.is_set():
            if interval > 0:
                next_at = start + slot * interval
                delay = next_at - self.clock()
                if delay > 0:
                    self.flush()
                    if self.stop_event.wait(delay):
                        break
                slot += 1
                late = int((self.clock() - start) / interval) + 1 - slot
                if late > 0:  # a long read overran whole slots: skip them
                    slot += late
                    self.stats.skipped(late)
                    self._event("skipped", f"{late} poll slot(s) of {interval:g} s skipped: "
                                f"the polls of slot {slot - late - 1} ran "
                                f"{self.clock() - next_at:.3f} s")
            elif all(d.retry_at > self.clock() for d in self.devices):
                self.flush()
                if not self._wait_for_a_device():
                    break
                continue
            for dev in self.devices:
                if self.stop_event.is_set():
                    break
                if dev.retry_at > self.clock():
                    continue  # backed off
                if not self._poll(dev):
                    return

    def _poll(self, dev: _Device) -> bool:
        """Read one device; False when the bus is gone for good (stopping)."""
        try:
            data = dev.read()
        except ModbusConnectionError as e:
            self._fault(dev, event_kind(e), str(e), getattr(e, "errno", None))
            self.client.close()
            if not self._connect():
                return False
            self._event("reconnect", f"reconnected to {self.bus.endpoint}")
            return True
        except ModbusError as e:
            code = getattr(e, "code", None) or getattr(e, "errno", None)
            self._fault(dev, event_kind(e), str(e), code)
            return True
        if dev.hub is not None and data.unsupported_mask == ALL_BLOCKS:
            # Every block "unsupported": the device supplied no value at all.
            # Not a sample: a fault, and the next try probes the blocks again.
            if not dev.explained:
                dev.explained = self._explain(dev)
            dev.hub.forget_firmware()
            self._fault(dev, "no_value", f"{dev.info.name} supplied no value: {dev.explained}",
                        None, at_once=True)
            return True
        batch = self._batch
        now = time.monotonic()
        if not batch:
            self._batch_since = now
        batch.append(Sample(dev.info, time.time(), now, data))
        if len(batch) >= BATCH_MAX or now - self._batch_since >= _BATCH_AGE:
            self.flush()
        if dev.failures:
            dev.failures, dev.backoff, dev.explained = 0, 0.0, ""
        self.stats.ok(dev.info.name)
        return True

    def _explain(self, dev: _Device) -> str:
        try:
            found = identify(client_asker(self.client), dev.info.address)
        except ModbusError as e:
            return str(e)
        return mismatch(found, dev.info.type, dev.info.address, dev.config.channels)

    def _fault(self, dev: _Device, kind: str, message: str, code: int | None, *,
               at_once: bool = False) -> None:
        dev.failures += 1
        retry = ""
        if at_once or dev.failures >= _FAULTS_BEFORE_BACKOFF:
            dev.backoff = min(max(dev.backoff * 2, _BACKOFF_FIRST), _BACKOFF_MAX)
            dev.retry_at = self.clock() + dev.backoff
            retry = f"; next try in {dev.backoff:g} s"
        self.stats.fault(dev.info.name, f"{dev.info.name}: {short_fault(kind, message)}")
        self._event(kind, message + retry, dev.info, code)


