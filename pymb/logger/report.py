"""What a poller hands the writer: :class:`Report`, the one hand-over of
both runners (a bus's thread and the one TCP loop): samples and polls in lists
(:data:`~pymb.logger.schedule.BATCH_MAX`, :data:`~pymb.logger.schedule.BATCH_AGE`),
a bus thread's polls of map groups as columns of one
:class:`~pymb.store.block.PollBlock` a list (:meth:`Report.poll`: no record
a poll), the polls the TCP loop's C part carried in blocks,
events at once, after the samples before them, and the run's counts
(:class:`~pymb.logger.stats.Stats`) for each fact of the schedule, each
said in one place with :data:`~pymb.logger.schedule.TEXT`."""

from __future__ import annotations

import queue
import time
from collections.abc import Sequence

from pymb.errors import ModbusError
from pymb.logger.schedule import BATCH_AGE, BATCH_MAX, TEXT, Health, Slot
from pymb.logger.stats import Stats
from pymb.store import DeviceInfo, Event, Sample
from pymb.store.block import PollBlock, PollSource
from pymb.store.records import event_kind, short_fault

__all__ = ["Report"]

_NONE: frozenset[int] = frozenset()


class Report:
    """A poller's samples and events on their way to the writer (``out``),
    and its part of the run's counts (``stats``)."""

    def __init__(self, out: queue.Queue[list[Sample | Event | PollBlock]], stats: Stats) -> None:
        self.out = out
        self.stats = stats
        self.items: list[Sample | Event | PollBlock] = []
        self.since = 0.0  #: when the oldest of :attr:`items` was read (monotonic)
        # the open block of :meth:`poll`: its columns, and its wall time less
        # monotonic time (read when it opened)
        self._sources: list[PollSource] = []
        self._monos: list[float] = []
        self._offs: list[int] = []
        self._data = bytearray()
        self._unread: list[frozenset[int]] | None = None
        self._clock = 0.0

    # -- the hand-over ------------------------------------------------------------------

    def flush(self) -> None:
        """Hand what was read since the last list to the writer."""
        if self._monos:
            self._close()
        items, self.items = self.items, []
        if items:
            self.out.put(items)

    def take(self) -> list[Sample | Event | PollBlock]:
        """What was read but not handed over (for the writer, once the poller
        is left behind at stop)."""
        if self._monos:
            self._close()
        items, self.items = self.items, []
        return items

    def aged(self, now: float) -> bool:
        """Whether samples wait that are to be handed over by ``now``."""
        return bool(self.items or self._monos) and now - self.since >= BATCH_AGE

    def sample(self, sample: Sample) -> None:
        """Add a sample to the list (handed over when full or old)."""
        if self._monos:  # (after the polls before it)
            self._close()
        items = self.items
        now = sample.monotonic
        if not items:
            self.since = now
        items.append(sample)
        if len(items) >= BATCH_MAX or now - self.since >= BATCH_AGE:
            self.flush()

    def poll(self, source: PollSource, mono: float, image: bytes | bytearray,
             unread: frozenset[int] = _NONE) -> None:
        """Add a poll of ``source`` read at ``mono`` (monotonic) to the list,
        in the open block of polls: its registers ``image`` (big-endian, laid
        out as the source's decoder says), ``unread`` the planner items the
        device refused. What :meth:`sample` of its
        :func:`~pymb.store.block.poll_sample` would hand over, as columns
        (the block's wall time is its first poll's; the others' are their
        monotonic times on the same clock)."""
        monos = self._monos
        if not monos:
            if not self.items:
                self.since = mono
            self._clock = time.time() - time.monotonic()
        data = self._data
        gone = self._unread
        if unread:
            if gone is None:
                gone = self._unread = [_NONE] * len(monos)
            gone.append(unread)
        elif gone is not None:
            gone.append(_NONE)
        self._sources.append(source)
        self._offs.append(len(data))
        monos.append(mono)
        data += image
        if len(monos) + len(self.items) >= BATCH_MAX or mono - self.since >= BATCH_AGE:
            self.flush()

    def _close(self) -> None:
        """The open block of polls joins the list."""
        monos = self._monos
        self.items.append(PollBlock.of(self._clock + monos[0], monos[0], self._sources, monos,
                                       self._offs, self._data, self._unread))
        self._sources, self._monos, self._offs, self._data = [], [], [], bytearray()
        self._unread = None

    def block(self, block: PollBlock) -> None:
        """Hand a block of polls over (with what waits before it): it is a
        list's worth already (:data:`~pymb.logger.schedule.BATCH_MAX`,
        :data:`~pymb.logger.schedule.BATCH_AGE`)."""
        if self._monos:
            self._close()
        self.items.append(block)
        self.flush()

    def event(self, bus: str, kind: str, message: str, device: DeviceInfo | None = None,
              code: int | None = None) -> None:
        """Record an event of ``bus`` now (handed over at once)."""
        self._add_event(bus, kind, message, device, code)
        self.flush()

    def _add_event(self, bus: str, kind: str, message: str, device: DeviceInfo | None = None,
                   code: int | None = None) -> None:
        if self._monos:  # (after the polls before it)
            self._close()
        self.items.append(Event(time.time(), time.monotonic(), bus, device, kind, code,
                                message))

    # -- the facts ---------------------------------------------------------------------

    def opened(self, bus: str) -> None:
        """``bus`` is open."""
        self.stats.opened[bus] = True
        self.stats.ok(bus)

    def bus_fault(self, bus: str, why: str, kind: str, message: str) -> None:
        """A fault of ``bus`` itself (``why``, the status line's), not of a
        device's poll: an event of ``kind``."""
        self.stats.fault(bus, f"bus {bus}: {why}")
        self.event(bus, kind, message)

    def not_open(self, bus: str, why: str, wait: float) -> None:
        """``bus`` did not open (``why``); tried again ``wait`` seconds later."""
        self.bus_fault(bus, why, "connection", TEXT["retrying"].format(why=why, wait=wait))

    def connected(self, bus: str, endpoint: str, devices: int) -> None:
        """``bus`` opened for the first time in the run: polling begins."""
        self.event(bus, "connect", TEXT["connect"].format(devices=devices, endpoint=endpoint))

    def reconnected(self, bus: str, endpoint: str) -> None:
        """``bus`` opened again after a failure."""
        self.event(bus, "reconnect", TEXT["reconnect"].format(endpoint=endpoint))

    def skipped(self, bus: str, slot: Slot, late: int) -> None:
        """A read of ``slot`` overran ``late`` whole slots (:meth:`Slot.advance`)."""
        # The event joins the items with the count (what the writer takes at the
        # stop); handed over after, without the counts' lock: the hand-over waits
        # while the writer's queue is full, and the writer takes that lock.
        self.stats.skipped(late, lambda: self._add_event(bus, "skipped", slot.skipped(late)))
        self.flush()

    def failed(self, bus: str, h: Health, info: DeviceInfo, kind: str, message: str,
               code: int | None, now: float, *, at_once: bool = False,
               why: str | None = None) -> None:
        """A poll of ``h``'s device failed at ``now``: counted, and an event of
        ``kind`` that says when the next try is once the device is left alone
        (``why``: the status line's and summary's words, if not the kind's)."""
        retry = h.failed(now, at_once)
        stats = self.stats
        if h.retry is not None:  # a map device's (the summary's health lines)
            stats.count(stats.device_faults, h.name, 1)
        stats.fault(h.name, f"{h.name}: {why or short_fault(kind, message)}")
        self.event(bus, kind, message + retry, info, code)

    def error(self, bus: str, h: Health, info: DeviceInfo, e: ModbusError, now: float) -> None:
        """:meth:`failed` with error ``e``."""
        code = getattr(e, "code", None) or getattr(e, "errno", None)
        kind, message = event_kind(e), str(e)
        # a timeout after something came (a reply cut short, or one under another
        # transaction id) is said whole, as a protocol fault is: the device is not silent
        self.failed(bus, h, info, kind, message, code, now,
                    why=message if kind == "timeout" and e.response else None)

    def answered(self, bus: str, h: Health, info: DeviceInfo,
                 refused: Sequence[str] = ()) -> None:
        """A poll of ``h``'s device gave a sample (whose ``refused`` points
        the device refused): an ``online`` event if it was offline."""
        stats = self.stats
        if refused:
            stats.refused(h.name, refused)
        if (h.failures or h.offline) and h.answered():
            self.event(bus, "online", TEXT["online"].format(name=h.name), info)
        if h.name in stats.problems:  # (a call a poll less when all is well)
            stats.ok(h.name)
