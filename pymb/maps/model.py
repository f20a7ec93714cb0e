"""The data model of a loaded map: :class:`Map` over the records of
:mod:`pymb.maps.point`. Everything is immutable; :meth:`Map.configure` makes a
new map for other option values."""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Protocol

from pymb.errors import InvalidArgument
from pymb.maps import codec
from pymb.maps.device_plan import map_planner
from pymb.maps.planner import Line, ReadPlan
from pymb.maps.point import (
    DeviceSection,
    Identify,
    Limits,
    MapError,
    Point,
    PointState,
    Timing,
    Value,
    did_you_mean,
)
from pymb.wire import DEFAULT_BAUD

__all__ = ["DeviceSection", "Identify", "Limits", "Map", "MapError", "Point", "PointState",
           "Timing", "Value", "did_you_mean"]


class Source(Protocol):
    """What a map was built from (:class:`pymb.maps.loader.CheckedFile`): it builds
    the map again for other option values. A protocol, so that the model
    needs nothing from the loader, which sits above it."""

    def configure(self, m: Map, given: Mapping[str, object]) -> Map:
        """``m`` with the option values in ``given``."""
        ...


@dataclass(frozen=True, eq=False)
class Map:
    """A loaded ``pymb.map/1`` file (see :func:`pymb.maps.load`).

    ``points`` maps each name to its :class:`Point`, in file order, for the
    option values in ``options`` (the defaults unless :meth:`configure`
    chose others). ``groups`` maps each group to its polling interval (s).
    """

    source: str
    device: DeviceSection
    limits: Limits
    timing: Timing
    groups: Mapping[str, float]
    points: Mapping[str, Point]
    identify: tuple[Identify, ...]
    options: Mapping[str, int | float]
    _file: Source = field(repr=False)

    @property
    def id(self) -> str:
        """The device TYPE (``device.id``)."""
        return self.device.id

    @property
    def state_names(self) -> tuple[str, ...]:
        """Every state name by its code: the fixed ones, then this map's own
        marker names from code 16 up."""
        return codec.state_names(self)

    def with_scale_factors(self, names: Iterable[str]) -> tuple[str, ...]:
        """``names`` and, after them, the ``scale_from`` points they need that
        are not among them: what a read of ``names`` must read."""
        out = dict.fromkeys(names)
        for n in list(out):
            sf = self.points[n].scale_from
            if sf is not None:
                out.setdefault(sf)
        return tuple(out)

    def polled(self, group: str) -> str:
        """How ``group`` is polled (its ``poll``): ``"interval"`` (every its
        interval; 0: once after the device (re)appears), ``"bus"`` (at the
        interval of the bus the device is on) or ``"request"`` (never polled:
        read when a read asks for it)."""
        return dict(self.timing.polls).get(group, "interval")

    def point(self, name: str) -> Point:
        """The point called ``name``; a :class:`MapError` with a did-you-mean if none."""
        if not isinstance(name, str):
            raise InvalidArgument(f"{self.source}: a point name is text, got {name!r}")
        try:
            return self.points[name]
        except KeyError:
            hint = did_you_mean(name, list(self.points))
            raise MapError(f"{self.source}: no point {name!r}{hint}", source=self.source,
                           point=name) from None

    def configure(self, options: Mapping[str, object] | None = None, **kw: object) -> Map:
        """This map with other option values (``channels=50``): numbers, or
        the strings of the device syntax ``TYPE:ADDRESS,name=value``."""
        if options is not None and not isinstance(options, Mapping):
            raise InvalidArgument(f"{self.source}: options are a mapping of names to values, "
                                  f"got {type(options).__name__}")
        return self._file.configure(self, {**(options or {}), **kw})

    def decode(self, name: str, registers: Sequence[int], *,
               scale_factor: int | None = None) -> Value:
        """One point's value from its registers (bits for coil/discrete), the
        first channel's first register first; a block gives a list. A
        ``scale_from`` point needs its ``scale_factor`` (the value of the
        point it names; None: no value)."""
        return self.decode_state(name, registers, scale_factor=scale_factor)[0]

    def decode_state(self, name: str, registers: Sequence[int], *,
                     scale_factor: int | None = None) -> tuple[Value, PointState]:
        """(value, state name) of one point; a block gives two lists."""
        p = self.point(name)
        if scale_factor is not None and (isinstance(scale_factor, bool)
                                         or not isinstance(scale_factor, int)):
            raise InvalidArgument(f"{self.source}: a scale factor is a whole number, "
                                  f"got {scale_factor!r}")
        try:
            if not all(0 <= r <= 0xFFFF for r in registers):  # a TypeError for a non-number
                raise InvalidArgument(f"{self.source}: {name!r}: registers are whole numbers "
                                      f"0..65535, got {list(registers)!r:.60}")
            return codec.decode(p, registers, scale_factor)
        except TypeError:
            raise InvalidArgument(f"{self.source}: {name!r} decodes a sequence of register "
                                  f"(or bit) values, got {registers!r:.60}") from None

    def encode(self, name: str, value: object, *, current: Sequence[int] | None = None,
               scale_factor: int | None = None) -> list[int]:
        """The registers (bits for a coil) that write ``value`` to a writable
        point; refuses a read-only point, a value outside ``valid`` or the
        type's range, or a name ``values`` does not list
        (:class:`pymb.InvalidArgument`). ``bit``/``bits`` views and masked
        values need the register's ``current`` contents, a ``scale_from``
        point its ``scale_factor``. An unknown ``name`` is an
        :class:`~pymb.InvalidArgument` naming the closest ones."""
        try:
            p = self.point(name)
        except MapError as e:  # a write's argument: refused as any other
            raise InvalidArgument(str(e)) from None
        return codec.encode(p, value, current=current, check_access=True, sf=scale_factor)

    def plan(self, group: str | None = None, *, baudrate: int = DEFAULT_BAUD,
             bits_per_char: int = 10) -> ReadPlan:
        """The requests that read ``group``'s points (every readable point
        for None), planned with the device's limits and timing at
        ``baudrate``: iterate for ``.table``, ``.address``, ``.count``; see
        :mod:`pymb.maps.planner`."""
        check_group(self, group)
        if isinstance(baudrate, bool) or not isinstance(baudrate, int) or baudrate <= 0:
            raise InvalidArgument(f"{self.source}: baudrate is a number of bit/s, got {baudrate!r}")
        if group is not None and group not in self.groups:
            raise MapError(f"{self.source}: no group {group!r}"
                           f"{did_you_mean(group, list(self.groups))}", source=self.source,
                           key=group)
        planner, mi = map_planner(self, Line(baudrate, bits_per_char))
        return planner.plan(mi.wanted(mi.group(group)))

    def label(self, name: str, value: int) -> str | None:
        """The name ``values`` gives a raw value of the point, or None."""
        return self.point(name).values.get(value)

    def flag_names(self, name: str, value: int) -> list[str]:
        """The names of the point's ``flags`` set in ``value``, lowest bit first."""
        p = self.point(name)
        if isinstance(value, bool) or not isinstance(value, int):
            raise InvalidArgument(f"{self.source}: {name!r} flags come from a raw integer, "
                                  f"got {value!r}")
        return [n for bit, n in sorted(p.flags.items()) if value >> bit & 1]


def check_group(m: Map, group: object) -> None:
    """Refuse a ``group`` that is neither None nor text (an
    :class:`~pymb.InvalidArgument`); whether the map has it is the caller's
    check, with its own message."""
    if group is not None and not isinstance(group, str):
        raise InvalidArgument(f"{m.source}: a group name is text, got {group!r}")


def check_address(m: Map, address: object) -> int:
    """``address`` (the default for None) if the map's device takes it, else an
    :class:`~pymb.InvalidArgument` ``ID address must be LOW..HIGH, got X``."""
    address = m.device.default_address if address is None else address
    low, high = m.device.addresses
    if isinstance(address, bool) or not isinstance(address, int) or not low <= address <= high:
        raise InvalidArgument(f"{m.id} address must be {low}..{high}, got {address!r}")
    return address
