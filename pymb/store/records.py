"""What the logger hands to an output: :class:`Sample` and :class:`Event`
(with the :class:`DeviceInfo` they belong to), :class:`StoredSample` (a
sample read back), and :class:`Sink`, the protocol every output follows."""

from __future__ import annotations

import abc
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Generic, Protocol, TypeVar, runtime_checkable

from pymb.devices.readings import Reading, map_reading
from pymb.errors import (
    DeviceBusy,
    DeviceException,
    InvalidArgument,
    ModbusConnectionError,
    ModbusError,
    ModbusTimeout,
    ProtocolError,
)
from pymb.maps import Value

__all__ = ["FAULT_KINDS", "DeviceInfo", "Event", "PollSamples", "Sample", "Sink", "SinkBase",
           "SinkWrapper", "StoredSample", "as_sink", "event_kind", "own_sample_writes",
           "reading_value", "reading_values", "short_fault"]



@dataclass(frozen=True)
class DeviceInfo:
    """A logged device: its bus, port, type (``coolpro``/``hub`` or a map's id), address,
    name; for a hub, its channels (0: as read) and humidity unit (1 or 0.1 %,
    one for all channels or a tuple, one per channel)."""

    bus: str
    port: str
    type: str
    address: int
    name: str
    channels: int = 0
    humidity_unit: float | tuple[float, ...] = 0.1
    #: a map device: its map's TOML text (stored with its samples) and the
    #: options it was read with, as ``key=value`` pairs
    map_source: str = field(default="", compare=False, repr=False)
    map_options: tuple[tuple[str, float], ...] = ()
    #: a map device: deadbands by point name for on-change storage (over the map's)
    map_deadband: tuple[tuple[str, float], ...] = ()


@dataclass(frozen=True, init=False)
class Sample:
    """One reading of one device, time-stamped when it completed."""

    device: DeviceInfo
    time_utc: float
    monotonic: float
    data: Reading

    def __init__(self, device: DeviceInfo, time_utc: float, monotonic: float,
                 data: Reading) -> None:
        # a logger makes one a poll: its fields go straight into its own
        # __dict__ (the frozen dataclass's __init__ sets each through
        # object.__setattr__, 3x slower); a test checks that this sets every field
        d = self.__dict__
        d["device"] = device
        d["time_utc"] = time_utc
        d["monotonic"] = monotonic
        d["data"] = data


def reading_values(data: Reading, not_read: bool = False
                   ) -> list[tuple[int | None, str, Value, str | None]]:
    """(channel, point, value, state) of every value of a reading, by its
    map's points, in the order of the long CSV: a block's channel (1-based)
    or None, the point's name, the value (None or NaN for none) and its
    state's name. A reading of blocks only (a hub's sweep) is read channel
    by channel; a value an ``--on-change`` sample did not store (state
    ``not_read``) is left out unless ``not_read``."""
    data = map_reading(data)
    out: list[tuple[int | None, str, Value, str | None]] = []
    blocks = data.map.points
    if all(isinstance(v, list) and blocks[n].block for n, v in data.values.items()):
        cols = [(n, v, st) for n, v in data.values.items()
                if isinstance(v, list) and isinstance(st := data.states[n], list)]
        for ch in range(len(cols[0][1]) if cols else 0):
            out += [(ch + 1, n, v[ch], st[ch]) for n, v, st in cols
                    if not_read or st[ch] != "not_read"]
        return out
    for name, v in data.values.items():
        st = data.states.get(name)
        if isinstance(v, list) and blocks[name].block:
            out += [(ch, name, cv, cs)
                    for ch, (cv, cs) in enumerate(zip(v, st or [], strict=False), 1)
                    if not_read or cs != "not_read"]
        elif not_read or st != "not_read":
            out.append((None, name, v, st))
    return out


def reading_value(data: Reading, name: str,
                  channel: int | None = None) -> float | None:
    """Point ``name`` of a reading (a block's ``channel``, 1-based) as a
    number, NaN where there is none; None when the reading does not hold it
    (another group's sample, a channel an ``--on-change`` sample did not
    store)."""
    data = map_reading(data)
    if name not in data.values:
        return None
    got, state = data.values[name], data.states.get(name)
    if isinstance(got, list) and data.map.points[name].block:
        i = (channel or 1) - 1
        if not 0 <= i < len(got):
            return None
        got, state = got[i], state[i] if isinstance(state, list) else state
    if state == "not_read":
        return None
    return float(got) if isinstance(got, (int, float)) else math.nan


@dataclass(frozen=True)
class StoredSample(Sample):
    """A sample read back from a database (what :func:`samples_after`
    yields): the :class:`Sample` the logger wrote, decoded again from the
    stored registers, plus ``id``, its id in the database (unique and
    increasing). A hub channel an ``--on-change`` sample did not store has
    the state ``NOT_READ`` and no value. :func:`sample_dict` and
    :func:`sample_rows` take it as they take a live sample."""

    id: int


@dataclass(frozen=True)
class Event:
    """Something that happened instead of (or besides) a sample: a timeout,
    an exception code, a busy hub, an unplugged port, a reconnect."""

    time_utc: float
    monotonic: float
    bus: str
    device: DeviceInfo | None
    kind: str  #: timeout, protocol, exception, busy, connection, reconnect, ...
    code: int | None
    message: str


class Sink(Protocol):
    """What the logger writes to: every member is called, none is probed.
    :class:`SinkBase` gives an output the defaults, :class:`SinkWrapper` a
    sink that wraps another; :func:`as_sink` fits any object with ``write``,
    ``event``, ``commit`` and ``close``."""

    @property
    def keeps_samples(self) -> bool:
        """False when the sink is done with a sample once :meth:`write`
        returns (it copied or wrote what it needs): the logger may then read
        later hub sweeps into that sample's arrays."""
        ...

    def write(self, sample: Sample) -> None:
        """Add a sample to the current batch."""
        ...

    def write_batch(self, samples: Sequence[Sample]) -> None:
        """Add samples to the current batch, in order."""
        ...

    def event(self, event: Event) -> None:
        """Add an event to the current batch."""
        ...

    def commit(self) -> None:
        """Make the batch durable."""
        ...

    def close(self) -> None:
        """Commit and release the output."""
        ...

    def turn(self) -> bool:
        """The logger's loop, at each turn: True when the batch should be
        committed now."""
        ...

    def check(self) -> None:
        """Raise (an :class:`~pymb.errors.OutputError`) when the output is
        gone (its directory removed); called about once a second."""
        ...

    def restamp(self, offset: float) -> bool:
        """The wall clock stepped (``offset``: wall time less monotonic time
        now): re-stamp what was written with the old clock; False when this
        sink cannot."""
        ...


class PollSamples(Protocol):
    """Polls handed over in one block (:class:`pymb.store.block.PollBlock`,
    the TCP loop's): what an output that takes samples needs of them."""

    def samples(self) -> list[Sample]:
        """Each poll's sample, in order."""
        ...


def own_sample_writes(cls: type[SinkBase], base: type[SinkBase]) -> bool:
    """Whether sink class ``cls`` writes samples its own way: it defines
    ``write`` or ``write_batch`` over ``base``'s."""
    return cls.write is not base.write or cls.write_batch is not base.write_batch


class SinkBase(abc.ABC):
    """The defaults of an output: it keeps the samples it is given, writes a
    batch a sample at a time, never asks for a commit, has nothing to check
    and cannot re-stamp. An output defines :meth:`write`, :meth:`event`,
    :meth:`commit` and :meth:`close`."""

    @property
    def keeps_samples(self) -> bool:
        """True: the sink may keep what it is given."""
        return True

    @abc.abstractmethod
    def write(self, sample: Sample) -> None:
        """Add a sample to the current batch."""

    @abc.abstractmethod
    def event(self, event: Event) -> None:
        """Add an event to the current batch."""

    @abc.abstractmethod
    def commit(self) -> None:
        """Make the batch durable."""

    @abc.abstractmethod
    def close(self) -> None:
        """Commit and release the output."""

    def write_batch(self, samples: Sequence[Sample]) -> None:
        """Each sample's :meth:`write`, in order."""
        for sample in samples:
            self.write(sample)

    def write_block(self, block: PollSamples) -> None:
        """Each poll's sample of ``block``, in order, to :meth:`write_batch`."""
        self.write_batch(block.samples())

    def turn(self) -> bool:
        """Never asks for a commit."""
        return False

    def check(self) -> None:
        """Nothing to check."""
        return None

    def restamp(self, offset: float) -> bool:
        """Cannot re-stamp."""
        return False


S = TypeVar("S", bound=Sink)


class SinkWrapper(SinkBase, Generic[S]):
    """A sink in front of another (``sink``, of type ``S``): every member is
    the wrapped sink's unless the wrapper defines its own."""

    def __init__(self, sink: S) -> None:
        self.sink = sink

    @property
    def keeps_samples(self) -> bool:
        """As the wrapped sink."""
        return self.sink.keeps_samples

    def write(self, sample: Sample) -> None:
        """As the wrapped sink."""
        self.sink.write(sample)

    def write_batch(self, samples: Sequence[Sample]) -> None:
        """As the wrapped sink."""
        self.sink.write_batch(samples)

    def write_block(self, block: PollSamples) -> None:
        """As the wrapped sink, unless this wrapper writes samples its own way
        (:func:`own_sample_writes`): then each poll's sample to its own."""
        if isinstance(self.sink, SinkBase) and not own_sample_writes(type(self), SinkWrapper):
            self.sink.write_block(block)
        else:
            self.write_batch(block.samples())

    def event(self, event: Event) -> None:
        """As the wrapped sink."""
        self.sink.event(event)

    def commit(self) -> None:
        """As the wrapped sink."""
        self.sink.commit()

    def close(self) -> None:
        """As the wrapped sink."""
        self.sink.close()

    def turn(self) -> bool:
        """As the wrapped sink."""
        return self.sink.turn()

    def check(self) -> None:
        """As the wrapped sink."""
        self.sink.check()

    def restamp(self, offset: float) -> bool:
        """As the wrapped sink."""
        return self.sink.restamp(offset)


@runtime_checkable
class _BareOutput(Protocol):
    """The least an output has: ``write``, ``event``, ``commit``, ``close``."""

    def write(self, sample: Sample, /) -> object:
        """Add a sample."""
        ...

    def event(self, event: Event, /) -> object:
        """Add an event."""
        ...

    def commit(self) -> object:
        """Make what was added durable."""
        ...

    def close(self) -> object:
        """Release the output."""
        ...


class _Minimal(SinkBase):
    """An object with ``write``, ``event``, ``commit`` and ``close`` as a :class:`Sink`."""

    def __init__(self, out: _BareOutput) -> None:
        self.out = out

    def write(self, sample: Sample) -> None:
        self.out.write(sample)

    def event(self, event: Event) -> None:
        self.out.event(event)

    def commit(self) -> None:
        self.out.commit()

    def close(self) -> None:
        self.out.close()


def as_sink(out: object) -> SinkBase:
    """``out`` itself when it is a :class:`SinkBase`, else ``out`` with the
    defaults of one (it keeps the samples it is given; a batch is written a
    sample at a time). Refuses an object without ``write``, ``event``,
    ``commit`` and ``close``."""
    if isinstance(out, SinkBase):
        return out
    missing = [n for n in ("write", "event", "commit", "close")
               if not callable(getattr(out, n, None))]
    if missing or not isinstance(out, _BareOutput):
        raise InvalidArgument(f"a sink needs write, event, commit and close; "
                              f"{type(out).__name__} has no {', '.join(missing)}")
    return _Minimal(out)


_EVENT_KIND: list[tuple[type[BaseException], str]] = [
    (DeviceBusy, "busy"),
    (DeviceException, "exception"),
    (ModbusTimeout, "timeout"),
    (ProtocolError, "protocol"),
    (ModbusConnectionError, "connection"),
    (ModbusError, "error"),
]
#: the kinds of the events that mean a device gave no value (a fault): an error,
#: or a hub that answered with every block unsupported (``no_value``)
FAULT_KINDS = frozenset([*(k for _, k in _EVENT_KIND), "no_value"])


def event_kind(e: BaseException) -> str:
    """The kind of the event that records the error ``e`` (``busy``, ``timeout``, ...)."""
    return next(k for cls, k in _EVENT_KIND if isinstance(e, cls))


def short_fault(kind: str, message: str) -> str:
    """The status line's words for a fault of ``kind``."""
    if kind == "no_value":
        return message.split(": ", 1)[-1]
    if kind == "timeout":
        return "no reply (timeout)"
    return message.split(" on ", 1)[-1] if kind == "connection" else message
