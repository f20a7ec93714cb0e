"""The records a map is made of: :class:`Point`, the device's settings and
:class:`MapError`. The bottom of :mod:`pymb.maps`: the type table, the field
checks, the codec and the planner build on these; :class:`~pymb.maps.Map`
(in :mod:`pymb.maps.model`) sits above them all."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Protocol, TypeAlias, TypeVar

from pymb._native import MAX_READ_BITS, MAX_READ_REGISTERS
from pymb.errors import InvalidArgument, ModbusError, closest_hint
from pymb.maps.types import BIT_TABLES, TABLES

__all__ = [
    "MAX_GAP",
    "VIEWS",
    "DeviceSection",
    "Identify",
    "Limits",
    "MapError",
    "Point",
    "PointState",
    "Points",
    "Timing",
    "Value",
    "did_you_mean",
]

#: What a point decodes to: None where there is no value (a marker, NaN,
#: invalid text, unsupported); a list for blocks and ``raw``.
Value: TypeAlias = "int | float | str | bool | list[Value] | None"
#: A point's state name (``value``, ``offline``, a marker's name...); a block's
#: is a list of them, one a channel.
PointState: TypeAlias = "str | list[str]"

#: the most undeclared registers ``max_gap`` may name: one request reads at
#: most MAX_READ_REGISTERS, so a gap spans at most all but one of them
MAX_GAP = MAX_READ_REGISTERS - 1

_K = TypeVar("_K")
_V = TypeVar("_V")


def _empty() -> Mapping[_K, _V]:
    return MappingProxyType({})


class MapError(ModbusError, ValueError):
    """A mistake in a map file, or a name a map does not have.

    The message names the file (``source``), the point and the key; ``source``,
    ``point`` and ``key`` are also attributes (None where they do not apply).
    """

    source: str | None
    point: str | None
    key: str | None

    def __init__(self, message: str, *, source: str | None = None, point: str | None = None,
                 key: str | None = None) -> None:
        super().__init__(message)
        self.source = source
        self.point = point
        self.key = key


def did_you_mean(word: str, known: Sequence[str]) -> str:
    """``; did you mean 'x'?``, or the known names, or nothing when there are none."""
    hint = closest_hint(word, known)
    if hint or not known:
        return hint
    return f"; known: {', '.join(sorted(known))}"


#: The typed views pymb has of a device (``[device] view``), each named by
#: its device's shipped map, whose id it is: ``pymb.devices.CoolPro``'s and
#: ``pymb.devices.SensorHub``'s. A device whose map names one is read as the
#: view reads it, and its readings' outputs take the view's form.
VIEWS = ("coolpro", "hub")


@dataclass(frozen=True)
class Limits:
    """How requests to the device may be planned (contract section 4): a map's
    ``[device.limits]``, and what the read planner plans within."""

    max_registers: int = MAX_READ_REGISTERS  #: registers per FC 03/04 request (1..125)
    max_bits: int = MAX_READ_BITS  #: bits per FC 01/02 request (1..2000)
    #: undeclared registers a request may span (0..MAX_GAP); None (unset): any
    #: gap inside ``readable`` where the map declares it, else none
    max_gap: int | None = None
    #: table -> on-wire (first, last) ranges known to exist (inclusive)
    readable: Mapping[str, Sequence[tuple[int, int]]] = field(default_factory=_empty)
    split_on_exception: bool = True  #: exception 02/03 on a bridged read: stop bridging there
    single_point_requests: bool = False  #: one request per point
    #: "always": FC 16 even for one register; "auto": FC 06 for one, FC 16 for several
    write_multiple: str = "auto"
    mask_write: bool = False  #: FC 22 mask write for bit/bits/8-bit halves (no read first)
    #: (table, first, last, most): on-wire inclusive ranges where a request may
    #: read at most ``most`` registers (bits), the device's own rules
    ranges: Sequence[tuple[str, int, int, int]] = ()

    def __post_init__(self) -> None:
        if not 1 <= self.max_registers <= MAX_READ_REGISTERS:
            raise InvalidArgument(f"max_registers must be 1..{MAX_READ_REGISTERS}, "
                                  f"got {self.max_registers!r}")
        if not 1 <= self.max_bits <= MAX_READ_BITS:
            raise InvalidArgument(f"max_bits must be 1..{MAX_READ_BITS}, got {self.max_bits!r}")
        if self.max_gap is not None and not 0 <= self.max_gap <= MAX_GAP:
            raise InvalidArgument(f"max_gap must be 0..{MAX_GAP}, got {self.max_gap!r}")
        for table, first, last, most in self.ranges:
            if table not in TABLES or not 0 <= first <= last <= 65535 or not most >= 1:
                raise InvalidArgument(f"a range limit is (table, first, last, most), got "
                                      f"{(table, first, last, most)!r}")

    def max_count(self, table: str) -> int:
        """Registers (bits, for a bit table) one request may read."""
        return self.max_bits if table in BIT_TABLES else self.max_registers


@dataclass(frozen=True)
class Timing:
    """The device's timing, seconds; None: the bus's own value."""

    response_timeout: float | None = None
    turnaround: float = 0.0  #: silence the device needs after its reply
    inter_request_gap: float = 0.0  #: silence before each request to it
    after_connect: float = 0.0  #: wait after (re)connecting
    offline_after: int = 3  #: failed polls in a row before backing off
    offline_retry: float = 30.0  #: retry period once backed off
    #: tried again after a doubling wait once backed off, not every
    #: ``offline_retry``; a poll of no value at all is a failure
    backoff: bool = False
    #: (group, how it is polled) of the groups not polled every their
    #: ``interval``: ``"bus"`` (at the bus's interval) or ``"request"``
    polls: tuple[tuple[str, str], ...] = ()


@dataclass(frozen=True)
class DeviceSection:
    """A map's ``[device]`` section: what the device is (id, manufacturer,
    model), its defaults (address, table, byte order) and its options."""

    id: str
    manufacturer: str = ""
    model: str = ""
    description: str = ""
    ref: str = ""
    default_address: int = 1
    addresses: tuple[int, int] = (1, 247)  #: unit ids it can take, inclusive
    address_base: int = 0  #: 0: addresses in the file are on-wire; 1: numbers from 1
    table: str = "holding"  #: default table of points
    order: str = "ABCD"  #: default byte order of points
    #: option name -> default
    options: Mapping[str, int | float] = field(default_factory=_empty)
    #: option name -> the values it may take, where the file lists them
    option_values: Mapping[str, tuple[int | float, ...]] = field(default_factory=_empty)
    #: option name -> (min, max), where the file gives them
    option_ranges: Mapping[str, tuple[float, float]] = field(default_factory=_empty)
    #: writes of each point allowed in any sliding hour (None: no budget)
    max_writes_per_hour: int | None = None
    #: the typed view the device is read through (one of :data:`VIEWS`), "" none
    view: str = ""


@dataclass(frozen=True)
class Identify:
    """One ``[[identify]]`` rule: how ``pymb scan`` recognises the device."""

    point: str
    range: tuple[float, float] | None = None
    equals: int | float | str | None = None  #: a number, or a text
    regex: str | None = None


@dataclass(frozen=True, slots=True)
class Point:
    """One value of a map (a ``[[point]]``), or a ``[[block]]`` of ``channels``
    values ``stride`` registers apart.

    ``address`` is on the wire (``address_base`` applied) and is the first
    channel's; ``count`` is the registers one value spans (bits for coil and
    discrete points); ``order`` is the explicit byte permutation of the value
    (``"CDAB"``, ``"BADCFEHG"``; ``"AB"``/``"BA"`` for strings: swapped in each
    register or not; empty for ``bool`` and ``raw``). ``scale`` and ``offset``
    are None when the file gives none: an integer type then decodes to an
    exact ``int``.
    """

    name: str
    table: str
    address: int
    count: int
    type: str
    order: str = ""
    channels: int = 1
    stride: int = 0
    block: bool = False
    scale: float | None = None
    offset: float | None = None
    #: raw value (its unsigned bit pattern) -> state name
    markers: Mapping[int, str] = field(default_factory=_empty)
    #: markers with don't-care bits: (pattern, care mask, state name), in file
    #: order; one matches when ``raw & care == pattern`` (after ``markers``)
    marker_masks: tuple[tuple[int, int, str], ...] = ()
    #: the name of the ``sunssf`` (or ``i16``) point whose value SF scales
    #: this one: value = raw x 10^SF
    scale_from: str | None = None
    #: the value is ``raw & mask`` (the bits under the mask, not shifted)
    mask: int | None = None
    #: the point is a view of the registers of this other point
    view_of: str | None = None
    values: Mapping[int, str] = field(default_factory=_empty)  #: raw value -> name
    flags: Mapping[int, str] = field(default_factory=_empty)  #: bit number -> name
    access: str = "r"
    valid: tuple[float, float] | None = None
    group: str | None = None
    deadband: float | None = None
    precision: int | None = None
    unit: str = ""
    kind: str = "gauge"
    description: str = ""
    ref: str = ""
    bit: int | None = None  #: for ``bit``
    shift: int | None = None  #: for ``bits``
    width: int | None = None  #: for ``bits``: bits in the field
    string_bytes: str = "both"
    encoding: str = "ascii"
    example: Value = None
    min_firmware: str = ""
    when: Mapping[str, int | float] = field(default_factory=_empty)
    #: writes allowed in any sliding hour (the point's own or ``[device]``'s; None: no budget)
    max_writes_per_hour: int | None = None

    @property
    def end(self) -> int:
        """One past the last register (or bit) of the last channel."""
        return self.address + (self.channels - 1) * self.stride + self.count

    @property
    def span(self) -> int:
        """Registers (or bits) from the first channel's first to the last's last."""
        return self.end - self.address

    def address_of(self, channel: int) -> int:
        """On-wire address of ``channel`` (1-based) of a block."""
        if isinstance(channel, bool) or not isinstance(channel, int) or not (
                1 <= channel <= self.channels):
            raise MapError(f"point {self.name!r} has channels 1..{self.channels}, "
                           f"not {channel!r}", point=self.name)
        return self.address + (channel - 1) * self.stride

    @property
    def writable(self) -> bool:
        """True for ``rw`` and ``w`` points."""
        return self.access != "r"


class Points(Protocol):
    """What the codec's state table and the planner need of a map: its
    points, limits and timing. :class:`~pymb.maps.Map` is one; the modules
    below the model take this, so none of them imports the model."""

    @property
    def points(self) -> Mapping[str, Point]:
        """Each point by its name, in file order."""
        ...

    @property
    def limits(self) -> Limits:
        """How requests to the device may be planned."""
        ...

    @property
    def timing(self) -> Timing:
        """The device's timing."""
        ...
