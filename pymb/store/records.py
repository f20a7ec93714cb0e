"""What the logger hands to an output: :class:`Sample` and :class:`Event`
(with the :class:`DeviceInfo` they belong to), :class:`StoredSample` (a
sample read back), and :class:`Sink`, the protocol every output follows."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

from pymb.devices import CoolProTelemetry, HubReading
from pymb.devices.mapreading import MapReading
from pymb.errors import (
    DeviceBusy,
    DeviceException,
    ModbusConnectionError,
    ModbusError,
    ModbusTimeout,
    ProtocolError,
)

__all__ = ["FAULT_KINDS", "DeviceInfo", "Event", "Sample", "Sink", "StoredSample", "event_kind",
           "short_fault"]


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


@dataclass(frozen=True)
class Sample:
    """One reading of one device, time-stamped when it completed."""

    device: DeviceInfo
    time_utc: float
    monotonic: float
    data: CoolProTelemetry | HubReading | MapReading


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
    """What the logger writes to.

    A sink that is done with a sample when :meth:`write` returns (it has
    copied or written what it needs) may say so with a class attribute
    ``keeps_samples = False``: the logger then reads later hub sweeps into
    that sample's arrays. pymb's own sinks do; any other sink is assumed to
    keep what it is given.
    """

    def write(self, sample: Sample) -> None:
        """Add a sample to the current batch."""

    def event(self, event: Event) -> None:
        """Add an event to the current batch."""

    def commit(self) -> None:
        """Make the batch durable."""

    def close(self) -> None:
        """Commit and release the output."""


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
