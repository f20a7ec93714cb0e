"""The device facades for asyncio: :class:`AsyncCoolPro`,
:class:`AsyncSensorHub` and :class:`AsyncMapDevice`.

Each wraps the blocking facade of :mod:`pymb.devices` (its ``blocking``
twin, made on the async client's blocking client) and runs every call of it
on the client's line worker, in turn with the client's other requests: a
hub sweep (six requests, decoded in C) is one job, the same C call as the
blocking ``read_all``. ``poll(interval)`` reads again and again::

    async for reading in hub.poll(1.0):
        ...
"""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator, Awaitable, Callable, Iterable, Mapping, Sequence
from typing import ParamSpec, TypeVar

from pymb import maps
from pymb.aio._mirror import Forward, Mirror, Mirrored
from pymb.aio.client import AsyncClient
from pymb.devices import ReadPlan
from pymb.devices.coolpro import CoolPro, CoolProTelemetry
from pymb.devices.hub import HubReading, SensorHub
from pymb.devices.mapdevice import MapDevice
from pymb.devices.mapwrite import Budget
from pymb.devices.polls import Slot
from pymb.errors import InvalidArgument
from pymb.maps import Map, PointState, Value
from pymb.maps.device_plan import PointPlanner

__all__ = ["AsyncCoolPro", "AsyncMapDevice", "AsyncSensorHub", "poll"]

_COOLPRO_ADDRESS = maps.builtin("coolpro").device.default_address
_HUB_ADDRESS = maps.builtin("hub").device.default_address
_HUB_CHANNELS = int(maps.builtin("hub").options["channels"])

P = ParamSpec("P")
R = TypeVar("R")


def _interval(interval: float) -> float:
    if isinstance(interval, bool) or not isinstance(interval, (int, float)) or not (
            0 <= interval <= 86400):
        raise InvalidArgument(f"poll interval must be 0 to 86400 seconds, got {interval!r}")
    return float(interval)


async def poll(read: Callable[[], Awaitable[R]], interval: float) -> AsyncIterator[R]:
    """``await read()`` every ``interval`` seconds (0: again at once, after
    giving the loop its turn) and yield each result. Reads start on a fixed
    grid (start + k * interval); a read that overruns its slot skips the
    slots it missed, never bunches reads to catch up (the one schedule's
    :class:`~pymb.devices.polls.Slot`). An exception from a read ends the
    iteration and propagates."""
    slot = Slot.every(_interval(interval))
    loop = asyncio.get_running_loop()
    slot.next_at = loop.time()
    while True:
        yield await read()
        now = loop.time()
        slot.advance(now)  # overran: on to the next slot of the grid still ahead
        await asyncio.sleep(max(slot.next_at - now, 0.0))


class _Facade(Mirrored):
    """A blocking facade run on an async client's worker."""

    blocking: CoolPro | SensorHub | MapDevice  #: the blocking facade it runs

    def __init__(self, client: AsyncClient) -> None:
        if not isinstance(client, AsyncClient):
            raise InvalidArgument(f"an async facade needs a pymb.aio client, got "
                            f"{type(client).__name__} (use pymb.devices with a blocking one)")
        self.client = client

    def _submit(self, fn: Callable[P, R], /, *args: P.args,
                **kwargs: P.kwargs) -> Awaitable[R]:
        return self.client.run(fn, *args, **kwargs)

    address = Forward[int](
        "The device's address (a CoolPro's changes at a reset after set_address).")


class AsyncCoolPro(_Facade):
    """The CoolPro at ``address`` on an async ``client``: the methods of
    :class:`pymb.devices.CoolPro`, as coroutines; :meth:`poll` yields
    telemetry."""

    blocking: CoolPro  #: the blocking facade run on the client's worker

    def __init__(self, client: AsyncClient, address: int = _COOLPRO_ADDRESS) -> None:
        super().__init__(client)
        self.blocking = CoolPro(client.blocking, address)

    @property
    def address(self) -> int:
        """The device address this object talks to; a new value (checked at
        once) applies to the calls not yet started, as the client's ``slave``."""
        return self.blocking.address

    @address.setter
    def address(self, address: int) -> None:
        self.blocking.address = address

    read_telemetry = Mirror(CoolPro.read_telemetry)
    read_identity = Mirror(CoolPro.read_identity)
    read_config = Mirror(CoolPro.read_config)
    set_address = Mirror(CoolPro.set_address)
    set_baud_rate = Mirror(CoolPro.set_baud_rate)
    reset = Mirror(CoolPro.reset)

    def poll(self, interval: float) -> AsyncIterator[CoolProTelemetry]:
        """Telemetry every ``interval`` seconds (see :func:`poll`)."""
        _interval(interval)
        return poll(self.read_telemetry, interval)

    def __repr__(self) -> str:
        return f"<AsyncCoolPro {self.address} on {self.client!r}>"


class AsyncSensorHub(_Facade):
    """The sensor hub at ``address`` on an async ``client``: the arguments
    and methods of :class:`pymb.devices.SensorHub`, the reads as coroutines;
    :meth:`poll` yields readings."""

    blocking: SensorHub  #: the blocking facade run on the client's worker

    def __init__(self, client: AsyncClient, address: int = _HUB_ADDRESS,
                 channels: int = _HUB_CHANNELS, humidity_unit: float | Sequence[float] = 0.1,
                 *, busy_retries: int = 3, busy_backoff: float = 0.02,
                 turnaround: float = 0.005) -> None:
        super().__init__(client)
        self.blocking = SensorHub(client.blocking, address, channels, humidity_unit,
                                  busy_retries=busy_retries, busy_backoff=busy_backoff,
                                  turnaround=turnaround)

    channels = Forward[int]("How many channels the hub has.")

    unsupported = Forward[frozenset[str]](
        "Blocks this hub's firmware lacks, as far as seen so far.")

    def plan(self, blocks: Iterable[str] | None = None,
             channels: Iterable[int] | None = None) -> ReadPlan:
        """The requests a read would make (no I/O; see :meth:`SensorHub.plan`)."""
        return self.blocking.plan(blocks, channels)

    read_all = Mirror(SensorHub.read_all)
    read = Mirror(SensorHub.read)
    forget_firmware = Mirror(SensorHub.forget_firmware)

    def poll(self, interval: float, blocks: Iterable[str] | None = None,
             channels: Iterable[int] | None = None) -> AsyncIterator[HubReading]:
        """A reading every ``interval`` seconds (see :func:`poll`): every
        block of every channel, or ``blocks`` and/or ``channels`` as in
        :meth:`read`. Each reading is a new one, the caller's to keep."""
        _interval(interval)
        # kept as tuples (an iterator is read once); anything else goes to
        # plan as given, which refuses it here rather than at the first read
        b = tuple(blocks) if isinstance(blocks, Iterable) else blocks
        c = tuple(channels) if isinstance(channels, Iterable) else channels
        self.plan(b, c)
        return poll(lambda: self.read(b, c), interval)

    def __repr__(self) -> str:
        return f"<AsyncSensorHub {self.address} on {self.client!r}>"


class AsyncMapDevice(_Facade):
    """The device map ``m`` describes, at ``address`` on an async ``client``:
    the arguments and methods of :class:`pymb.devices.MapDevice`, the reads
    and writes as coroutines (``await meter.read(group="fast")``), with the
    map's timing kept on the worker; :meth:`poll` yields ``name -> value``
    dictionaries."""

    blocking: MapDevice  #: the blocking device run on the client's worker

    def __init__(self, client: AsyncClient, m: Map, address: int | None = None, *,
                 options: Mapping[str, object] | None = None,
                 baudrate: int | None = None, budget: Budget | None = None,
                 busy_retries: int = 0, busy_backoff: float = 0.02,
                 plan_turnaround: float | None = None,
                 split_on: Iterable[int] = (2, 3)) -> None:
        super().__init__(client)
        self.blocking = MapDevice(client.blocking, m, address, options=options,
                                  baudrate=baudrate, budget=budget, busy_retries=busy_retries,
                                  busy_backoff=busy_backoff, plan_turnaround=plan_turnaround,
                                  split_on=split_on)

    map = Forward[Map]("The device's map (configured with its options).")

    states = Forward[dict[str, PointState]](
        "The state of each point of the last read that finished.")

    planner = Forward[PointPlanner](
        "The device's read planner (see :attr:`MapDevice.planner`).")

    def plan(self, group: str | None = None, *names: str,
             channels: Iterable[int] | None = None) -> ReadPlan:
        """The requests a read would make now (no I/O; see :meth:`MapDevice.plan`)."""
        return self.blocking.plan(group, *names, channels=channels)

    read = Mirror(MapDevice.read)
    read_group = Mirror(MapDevice.read_group)
    read_into = Mirror(MapDevice.read_into)
    fetch = Mirror(MapDevice.fetch)
    write = Mirror(MapDevice.write)
    write_many = Mirror(MapDevice.write_many)
    # a plan reads the scale factors its values need from the device: I/O
    plan_write = Mirror(MapDevice.plan_write)
    write_points = Mirror(MapDevice.write_points)

    def poll(self, interval: float, *names: str,
             group: str | None = None) -> AsyncIterator[dict[str, Value]]:
        """The named points, or ``group``'s, or all, every ``interval``
        seconds (see :func:`poll`), as :meth:`read` returns them."""
        _interval(interval)
        self.plan(group, *names)  # a mistake in names or group raises here, not at the first read
        return poll(lambda: self.read(*names, group=group), interval)

    def __repr__(self) -> str:
        return f"<AsyncMapDevice {self.map.id}:{self.address} on {self.client!r}>"
