"""The logger: runs the pollers (a thread per serial bus, one loop for every
map device on Modbus TCP) and writes what they produce to one sink."""

from __future__ import annotations

import contextlib
import gc
import math
import operator
import queue
import signal
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

from pymb.errors import OutputError
from pymb.logger.config import EVENT_COMMIT_INTERVAL, LogConfig
from pymb.logger.poller import BusPoller
from pymb.logger.schedule import BATCH_MAX
from pymb.logger.stats import Stats
from pymb.logger.tcploop import TcpMapPoller, fans_out
from pymb.service.clock import ClockWatch, restamped
from pymb.store import Event, Sample, Sink, SinkBase, as_sink, check_output, open_sink
from pymb.store.block import PollBlock, PollSource

__all__ = ["Logger", "RunSummary"]

#: a sample's device's name
_DEVICE_NAME = operator.attrgetter("device.name")
_REGISTERS = operator.attrgetter("data.registers")  #: a sample's registers
_STOP_WAIT = 0.1  #: seconds a stopping run waits for a poller in the middle of a request
_DRAIN_EVERY = 0.02  #: seconds the writer waits at most: on its queue, after a commit
_IDLE_CHECK = 1.0  #: seconds between looks at the storage when nothing is committed


@dataclass
class RunSummary:
    """What a logging run did."""

    samples: int
    events: int
    faults: int
    elapsed: float
    cpu: float  #: process CPU seconds used
    by_device: dict[str, int]
    skipped_slots: int
    path: str
    #: bus -> why its port never opened
    never_opened: dict[str, str] = field(default_factory=dict)
    #: device -> why it never delivered a sample (its last fault)
    silent: dict[str, str] = field(default_factory=dict)
    #: map device -> its failed polls (timeouts, exceptions, ...)
    device_faults: dict[str, int] = field(default_factory=dict)
    #: map device -> how many of its points it refused (read as ``unsupported``), each
    #: point once however many polls it was refused in
    unsupported: dict[str, int] = field(default_factory=dict)
    #: bus -> the exception that stopped its poller (a bug in pymb: it ends the run)
    crashed: dict[str, str] = field(default_factory=dict)

    @property
    def rate(self) -> float:
        """Samples per second over the run."""
        return self.samples / self.elapsed if self.elapsed > 0 else 0.0

    @property
    def exit_code(self) -> int:
        """0; 70 (EX_SOFTWARE) if a poller stopped on an internal error; else 4
        if some bus never opened its port; else 3 if some device never
        delivered a sample (``pymb log``'s exit code)."""
        return 70 if self.crashed else 4 if self.never_opened else 3 if self.silent else 0

    def headline(self) -> str:
        """``logged N samples (R/s) and E events (F faults[, K interval slot(s)
        skipped]) in T s to PATH``: the first line of the run's summary."""
        skipped = f", {self.skipped_slots} interval slot(s) skipped" if self.skipped_slots else ""
        return (f"logged {self.samples:,} samples ({self.rate:,.1f}/s) and {self.events} events "
                f"({self.faults} faults{skipped}) in {self.elapsed:.1f} s to {self.path}")

    def health(self) -> list[str]:
        """One line per map device that failed a poll or refused a point:
        ``NAME: 3 failed poll(s), 2 point(s) unsupported, 10 sample(s)``."""
        out = []
        for name in dict.fromkeys([*self.device_faults, *self.unsupported]):
            parts = []
            if self.device_faults.get(name):
                parts.append(f"{self.device_faults[name]} failed poll(s)")
            if self.unsupported.get(name):
                parts.append(f"{self.unsupported[name]} point(s) unsupported")
            parts.append(f"{self.by_device.get(name, 0)} sample(s)")
            out.append(f"{name}: {', '.join(parts)}")
        return out

    def problems(self) -> list[str]:
        """One line per bus whose poller failed, per bus that never opened and
        per device that never delivered."""
        out = [f"bus {b} stopped on an internal error (a bug in pymb): {why}"
               for b, why in self.crashed.items()]
        out += [f"bus {b} never opened its port: {why}" for b, why in self.never_opened.items()]
        out += [f"{d} delivered no sample: {why}" for d, why in self.silent.items()]
        return out


class _Crashes(threading.Thread):
    """A poller thread that keeps the exception that ended it, if any: that
    is a bug, which stops the run (its traceback goes to stderr) instead of
    leaving its buses silently unpolled."""

    crashed = ""
    stop_event: threading.Event

    def run(self) -> None:
        try:
            super().run()
        except Exception as e:
            self.crashed = f"{type(e).__name__}: {e}"
            self.stop_event.set()
            raise


class _Poller(_Crashes, BusPoller):
    """A bus's own poller thread."""


class _TcpPoller(_Crashes, TcpMapPoller):
    """The one loop over the TCP buses: every bus it polls stops with it."""



#: objects made (less those freed) between two young collections during a run:
#: what is in flight between the pollers and the writer (a few thousand at
#: most) never fills it, so a steady run collects nothing
_YOUNG = 10_000


class _Collector:
    """The garbage collector's settings while runs last: the first run to
    start sets them, the last to end gives back what the first found (runs
    in threads of one process may end in any order)."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.runs = 0
        self.threshold = gc.get_threshold()


_COLLECTOR = _Collector()


@contextlib.contextmanager
def _collector_quiet() -> Iterator[None]:
    """The garbage collector during a run. What exists when it starts (maps,
    plans, devices: most of the heap, and it lives as long as the run) is
    left out of its full passes; the young generation holds :data:`_YOUNG`
    objects (automatic collection left off if it was off). Flat out at 100
    TCP devices, a full pass over the heap took 35 ms every few seconds and
    the young ones 2 us a poll."""
    c = _COLLECTOR
    with c.lock:
        if c.runs == 0:
            c.threshold = threshold = gc.get_threshold()
            gc.freeze()
            if threshold[0]:
                gc.set_threshold(max(threshold[0], _YOUNG), *threshold[1:])
        c.runs += 1
    try:
        yield
    finally:
        with c.lock:
            c.runs -= 1
            if c.runs == 0:
                gc.set_threshold(*c.threshold)
                gc.unfreeze()


class Logger:
    """Runs the pollers and writes what they produce to one sink.

    The calling thread writes (batched commits) and calls ``tick`` (a status
line, the command line's) twice a second; :meth:`stop` (or SIGINT /
    SIGTERM when :meth:`run` installs handlers) ends the run at once: what
    was read is committed, and a poller still waiting for a reply is left to
    time out on its own (it is a daemon thread) rather than holding the
    stop up for its timeout.
    """

    def __init__(self, config: LogConfig, *, sink: Sink | None = None,
                 tick: Callable[[Logger, float, bool], None] | None = None) -> None:
        self.config = config
        #: called with (this logger, seconds since the start, final) twice a second
        #: during the run and once at its end (final True): a status line's hook
        self.tick = tick
        #: what SIGHUP does instead of stopping the run (a service's reload)
        self.on_hangup: Callable[[], None] | None = None
        self.clock = ClockWatch()  #: steps of the wall clock (events, re-stamping)
        if sink is None:
            check_output(config.format, config.path)
        self._stop = threading.Event()
        self._wake = threading.Event()  # the writer's pause after a commit ends (see wake())
        #: set by a signal handler: the run loop sees it within _DRAIN_EVERY
        self._signalled = False
        self.stats = Stats()
        #: the polls of the blocks written since the last commit, by source
        #: (:meth:`_count_carried` names them: a dict look-up a poll, no attribute walk)
        self._carried: Counter[PollSource] = Counter()
        # Bounded (about 2,000 samples): pollers wait when the writer lags (a
        # flat-out poller, a bounded memory).
        self._queue: queue.Queue[list[Sample | Event | PollBlock]] = queue.Queue(
            maxsize=2048 // BATCH_MAX)
        self.sink: SinkBase = as_sink(sink if sink is not None else open_sink(
            config.format, config.path, max_bytes=config.max_bytes, max_age=config.max_age,
            on_change=config.on_change))
        self.pollers: list[_Poller | _TcpPoller] = [
            _Poller(b, self._queue, self._stop, self.stats, decoded=config.on_change is not None)
            for b in config.buses if not fans_out(b)]
        tcp = [b for b in config.buses if fans_out(b)]
        if tcp:  # every map device on plain Modbus TCP: one thread, one loop
            self.pollers.append(_TcpPoller(tcp, self._queue, self._stop, self.stats))

    def stop(self) -> None:
        """Ask the run to end (thread-safe; a signal handler uses :meth:`_on_signal`)."""
        self._stop.set()
        self.wake()

    def wake(self) -> None:
        """End the writer's wait now, on its queue or after a commit (thread-safe):
        its sink's turn has work from another thread (a command desk's record)."""
        self._wake.set()
        with contextlib.suppress(queue.Full):  # (full: the writer takes a list at once)
            self._queue.put_nowait([])  # an empty list: a turn, nothing to write

    def _idle(self) -> None:
        """The writer's pause after a commit: :data:`_DRAIN_EVERY` at most."""
        self._wake.wait(_DRAIN_EVERY)
        self._wake.clear()

    def _on_signal(self, *_: object) -> None:
        """SIGINT/SIGTERM/SIGHUP: only a flag. ``Event.set()`` takes the event's
        lock, which the main thread holds for a moment in every ``Event.wait()``:
        a handler run there would wait for its own thread for ever."""
        self._signalled = True

    @contextlib.contextmanager
    def _signals(self) -> Iterator[None]:
        if threading.current_thread() is not threading.main_thread():
            yield
            return
        # SIGHUP (the terminal or ssh session closed) ends the run as SIGTERM
        # does, unless it is ignored (nohup): then it stays ignored.
        hup = [] if signal.getsignal(signal.SIGHUP) == signal.SIG_IGN else [signal.SIGHUP]
        old = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, *hup)}
        for s in old:
            signal.signal(s, self._on_signal)
        if hup and self.on_hangup is not None:
            hangup = self.on_hangup
            signal.signal(signal.SIGHUP, lambda *_: hangup())
        try:
            yield
        finally:
            for s, h in old.items():
                signal.signal(s, h)

    def run(self, seconds: float | None = None) -> RunSummary:
        """Log until stopped (or for ``seconds``); returns the summary."""
        t0, cpu0 = time.monotonic(), time.process_time()
        deadline = None if seconds is None else t0 + seconds
        last_status = t0
        pending = 0  # bytes of registers waiting for the commit
        due: float | None = None  # when what waits must be committed (monotonic)
        commit_every = self.config.commit_every
        # With nothing to commit, the storage is looked at every second (a removed
        # directory is noticed at any rate, none included).
        last_check = t0
        failure: OutputError | None = None
        with self._signals(), _collector_quiet():
            for p in self.pollers:
                p.start()
            try:
                while True:
                    if deadline is not None and time.monotonic() >= deadline:
                        self._stop.set()
                    if self._stop.is_set() or self._signalled:
                        break
                    # A poller hands over lists (of up to BATCH_MAX samples, or BATCH_AGE
                    # seconds' worth): woken by each list (or by wake()), not by each
                    # sample, and at least every _DRAIN_EVERY seconds for the stop, the
                    # commit and the checks below.
                    try:
                        item: list[Sample | Event | PollBlock] | None = self._queue.get(
                            timeout=_DRAIN_EVERY)
                    except queue.Empty:
                        item = None
                    now = time.monotonic()
                    # Before the list is written: a sample in it stamped after a step
                    # of the clock is re-stamped (a step after its stamp is seen here too).
                    self._watch_clock()
                    if item:
                        size, events = self._write_all(item)
                        pending += size
                        # The oldest of the list: when it was read (the loss bound
                        # counts from the read, not from the queue).
                        first = min(now, item[0].monotonic)
                        wait = min(commit_every, EVENT_COMMIT_INTERVAL) if events else \
                            commit_every
                        due = min(due if due is not None else math.inf, first + wait)
                    if self.sink.turn():
                        due = now
                    if due is not None and (pending >= self.config.commit_bytes or now >= due):
                        self.sink.commit()
                        self._count_carried()
                        pending, due = 0, None
                        # Leave SQLite's write lock free for a moment: another
                        # writer (the MQTT forwarder's cursor) gets its turn.
                        self._idle()
                    elif now - last_check >= _IDLE_CHECK:
                        self.sink.check()
                        last_check = now
                    if self.tick is not None and now - last_status >= 0.5:
                        self.tick(self, now - t0, False)
                        last_status = now
                    if not item and not any(p.is_alive() for p in self.pollers):
                        break
            except OutputError as e:
                failure = e
            finally:
                self._stop.set()
                # A poller in the middle of a request finishes it (its reply is
                # logged) if that takes less than _STOP_WAIT; one waiting out a
                # long timeout is left behind.
                until = time.monotonic() + _STOP_WAIT
                for p in self.pollers:
                    p.join(max(0.0, until - time.monotonic()))
                self.stats.close()
                try:
                    if failure is None:
                        self._watch_clock()
                    while failure is None:
                        try:
                            self._write_all(self._queue.get_nowait())
                        except queue.Empty:
                            break
                    # A poller left behind: what it read before the stop.
                    for p in self.pollers:
                        if failure is None and p.is_alive():
                            self._write_all(p.take_unflushed())
                    self.sink.close()
                except OutputError as e:
                    failure = failure or e
                self._count_carried()
        if failure is not None:
            raise failure
        elapsed = time.monotonic() - t0
        if self.tick is not None:
            self.tick(self, elapsed, True)
        s = self.stats
        crashed = {b: p.crashed for p in self.pollers if p.crashed
                   for b in ([p.bus.name] if isinstance(p, BusPoller) else p.bus_names)}
        never = {b.name: s.last_fault.get(b.name, "").split(": ", 1)[-1] or "not yet opened"
                 for b in self.config.buses if not s.opened.get(b.name) and b.name not in crashed}
        silent = {d.name: s.last_fault.get(d.name, f"{d.name}: no reply yet").split(": ", 1)[-1]
                  for b in self.config.buses if b.name not in never and b.name not in crashed
                  for d in b.devices if not s.by_device.get(d.name)}
        return RunSummary(s.samples, s.events, s.faults, elapsed, time.process_time() - cpu0,
                       dict(s.by_device), s.skipped_slots, self.config.path, never, silent,
                       dict(s.device_faults),
                       {k: len(v) for k, v in s.unsupported.items()}, crashed)

    def _watch_clock(self) -> None:
        """The wall clock looked at: a step becomes :meth:`_clock_step`."""
        if (step := self.clock.check()) is not None:
            self._clock_step(step)

    def _clock_step(self, step: float) -> None:
        """The wall clock stepped: an event, and what this run stored with the
        old clock re-stamped (when the sink can)."""
        restamped = not self.clock.held and self.sink.restamp(self.clock.offset)
        mono = time.monotonic()
        self.sink.event(Event(mono + self.clock.offset, mono, "clock", None, "clock", None,
                              self.clock.message(step, restamped)))
        self.stats.events += 1

    def _write_all(self, items: list[Sample | Event | PollBlock]) -> tuple[int, bool]:
        """Write a poller's list in order: each run of samples in one call
        when the sink takes batches (SQLite: multi-row INSERTs). Returns the
        list's weight for the commit: (bytes of registers, whether it had
        an event)."""
        run: list[Sample] = []
        size = 0
        events = False
        if self.clock.steps:  # some may have been stamped before the step came
            items = restamped(items, self.clock.offset)
        for item in items:
            if isinstance(item, Sample):
                run.append(item)
                continue
            if isinstance(item, PollBlock):  # the TCP loop's polls, carried in C
                size += self._samples(run)
                run = []
                self.sink.write_block(item)
                self._carried.update(item.sources)
                self.stats.samples += len(item)
                size += len(item.data)
                continue
            events = True
            size += self._samples(run)
            run = []
            self.sink.event(item)
            self.stats.events += 1
        return size + self._samples(run), events

    def _count_carried(self) -> None:
        """The polls of the blocks written (:attr:`_carried`) counted in
        :attr:`Stats.by_device <pymb.logger.stats.Stats.by_device>`: at each
        commit and at the end."""
        by_device = self.stats.by_device
        for src, n in self._carried.items():
            by_device[src.device.name] += n
        self._carried.clear()

    def _samples(self, samples: list[Sample]) -> int:
        """Write a run of samples; their bytes of registers."""
        if not samples:
            return 0
        self.sink.write_batch(samples)
        self.stats.by_device.update(map(_DEVICE_NAME, samples))
        self.stats.samples += len(samples)
        return 2 * sum(map(len, map(_REGISTERS, samples)))
