"""Fleet: every logged sample reaches an MQTT broker, through outages.

The SQLite log is the durable outbox: a
:class:`~pymb.fleet.forwarder.Forwarder` thread publishes each sample the
logger writes (at once, from the writer's open batch: its id is under the
writer's durable high-water mark, never given to another sample) and
advances a cursor stored in the same file only past what the broker
acknowledged; the backlog of an outage is published from the file.
Profiles: ``plain`` (JSON, QoS 1) and ``sparkplug`` (Sparkplug B 3.0).
Needs the extra ``pymb-modbus[mqtt]`` (paho-mqtt 2.x). Also here: a
launcher of Debian's mosquitto for tests, the demo and the bench (:mod:`pymb.fleet.broker`).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

from pymb.fleet.config import MqttConfig
from pymb.fleet.health import DeviceHealth
from pymb.store import Event, Sample, SinkWrapper, SqliteSink
from pymb.store.inwriter import InWriter
from pymb.store.outbox import write_pending

if TYPE_CHECKING:  # the forwarder needs paho, which this package's face must not
    from pymb.fleet.forwarder import Forwarder

__all__ = ["ForwardingSink", "MqttConfig"]


class ForwardingSink(SinkWrapper[SqliteSink]):
    """A sink that wakes the forwarder after each write (the writer hands it
    what it wrote, see :class:`~pymb.fleet.forwarder.Forwarder`) or
    commit of the sink it wraps, and records what happened to the broker
    connection as events (bus and kind ``mqtt``). It also follows which
    devices stop answering (:class:`~pymb.fleet.health.DeviceHealth`) and
    tells the forwarder (Sparkplug: DDEATH) once the news is written.
    ``echo``, when given, is called with every event stored (a service's
    lines on stderr), the broker's own included. Other threads' work on
    the file (a command desk's record) goes through :attr:`in_writer`,
    served at each of the logger's turns."""

    def __init__(self, sink: SqliteSink, forwarder: Forwarder,
                 echo: Callable[[Event], None] | None = None) -> None:
        super().__init__(sink)
        self.forwarder = forwarder
        self.echo = echo
        self.health = DeviceHealth()
        #: the forwarder takes what this writes before the commit (as data)
        self.handoff = forwarder.handoff
        self.live = self.handoff is not None
        #: another thread's work on the file, done in this (the writer's) thread
        self.in_writer = InWriter(sink)
        sink.on_commit(self._tell)
        sink.on_commit(lambda top: self.in_writer.committed())

    def write(self, sample: Sample) -> None:
        """Add a sample to the batch."""
        self.sink.write(sample)
        self.health.sample(sample)
        self._written()

    def write_batch(self, samples: Sequence[Sample]) -> None:
        """Add samples to the batch."""
        self.sink.write_batch(samples)
        for sample in samples:
            self.health.sample(sample)
        self._written()

    def event(self, event: Event) -> None:
        """Add an event to the batch."""
        self.sink.event(event)
        if self.echo is not None:
            self.echo(event)
        self.health.event(event)
        self._written()

    def _written(self) -> None:
        """A live forwarder hears of it now: the devices that went down (with
        the last id written) and the new samples."""
        if self.live:
            self._tell(self.sink.last_id)

    def turn(self) -> bool:
        """The logger's loop, at each turn: other threads' requests are run
        (:attr:`in_writer`) and the broker connection's events go into the
        batch; True when the batch should be committed now (those events,
        what a request wrote a while ago, or a forwarder's state that must
        be durable: the Sparkplug bdSeq)."""
        due = self.in_writer.serve()
        wrote = self._events()
        return wrote or due or (
            self.handoff is not None and self.handoff.commit_wanted.is_set())

    def commit(self) -> None:
        """Commit the batch with the broker's events and what the forwarder
        handed over to write (its cursor, its state); the store then calls
        :meth:`_tell`.

        The logger holds SQLite's write lock for most of each batch: the
        forwarder's writes go in with the batch rather than waiting for the lock."""
        self._events()
        self._pending()
        self.sink.commit()

    def _pending(self, closing: bool = False) -> None:
        handoff = self.handoff
        if handoff is not None:
            self.sink.in_batch(lambda db: write_pending(db, handoff, closing), False)

    def _tell(self, top: int) -> None:
        """Tell the forwarder the devices that went down, with ``top``, the
        highest sample id written with them (it publishes their DDEATH once it
        has sent everything up to it), then wake it."""
        downs = self.health.take()
        if downs:
            self.forwarder.devices_down(downs, top)
        self.forwarder.notify()

    def _events(self) -> bool:
        got = self.forwarder.take_events()
        for t, message in got:
            event = Event(t, time.monotonic(), "mqtt", None, "mqtt", None, message)
            self.sink.event(event)
            if self.echo is not None:
                self.echo(event)
        return bool(got)

    def close(self) -> None:
        """Commit (the broker's events and the cursor too) and close (the
        store's on-commit hook wakes the forwarder)."""
        self._events()
        try:
            self.in_writer.serve()
            self._pending(closing=True)
        finally:
            try:
                self.sink.close()
            finally:
                self.in_writer.close()
