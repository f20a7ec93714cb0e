"""The polls of map devices a TCP loop read in one go (one wait of its C
part), as columns: :class:`PollBlock`. The SQLite writer binds its rows
straight from a block (:func:`pymb.store.rows.block_rows`), with no record a
poll; any other output gets each poll's :class:`~pymb.store.Sample`
(:meth:`PollBlock.samples`), which :func:`poll_sample` makes.

A poll's registers are laid out as the store keeps a map reading
(:func:`pymb.devices.mapreading.group_layout`): each table's registers, from
its first point's to its last's, big-endian, one table after the other (a
bit as a 0/1 word).
"""

from __future__ import annotations

import sys
from abc import abstractmethod
from array import array
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, fields
from typing import Any

from pymb.devices.mapreading import GroupDecode, MapReading
from pymb.maps import Value
from pymb.store.records import DeviceInfo, Sample

__all__ = ["PollBlock", "PollSource", "poll_sample"]


@dataclass(frozen=True, eq=False)
class PollSource:
    """A polling group of a map device, as its polls name it: the device and
    the group's decoder (its map, its group, its registers' layout)."""

    device: DeviceInfo
    decode: GroupDecode


@dataclass(frozen=True, eq=False)
class PollBlock:
    """Polls read in one go, in the order they were read. Poll ``j`` is of
    ``sources[j]``, read at ``monos[j]`` (monotonic; its wall time
    ``clock + monos[j]``); its registers are ``data`` from ``offs[j]`` to
    the next poll's offset (the last: to the end), big-endian (a bytearray
    as the TCP loop hands it: the SQLite writer binds slices of it as they
    are, without a copy of the whole first); ``unread[j]``
    are the planner items the device refused in it (``unread`` None: none in
    any poll). ``time_utc`` and ``monotonic`` are the first poll's (the
    block's time, as a sample's: a clock step re-stamps it)."""

    time_utc: float
    monotonic: float
    sources: list[PollSource]
    monos: list[float]
    offs: list[int]
    data: bytes | bytearray
    unread: list[frozenset[int]] | None = None

    @classmethod
    def of(cls, time_utc: float, monotonic: float, sources: list[PollSource],
           monos: list[float], offs: list[int], data: bytes | bytearray,
           unread: list[frozenset[int]] | None = None) -> PollBlock:
        """The block its constructor makes, its fields set in one step (a
        frozen dataclass's ``__init__`` sets each with a call of
        ``object.__setattr__``: about three times the time; a TCP loop makes
        one block a wait of its C part)."""
        block = _new(cls)
        _set(block, "__dict__", {"time_utc": time_utc, "monotonic": monotonic,
                                 "sources": sources, "monos": monos, "offs": offs,
                                 "data": data, "unread": unread})
        return block

    def __len__(self) -> int:
        return len(self.sources)

    @property
    def clock(self) -> float:
        """Wall time less monotonic time, for every poll of the block."""
        return self.time_utc - self.monotonic

    def sample(self, j: int) -> Sample:
        """Poll ``j``'s :class:`~pymb.store.Sample` (its data a
        :class:`~pymb.devices.mapreading.MapReading`)."""
        src, offs, mono = self.sources[j], self.offs, self.monos[j]
        end = offs[j + 1] if j + 1 < len(offs) else len(self.data)
        image = bytes(memoryview(self.data)[offs[j]:end])
        return poll_sample(src.device, self.clock + mono, mono, src.decode, image,
                           self.unread[j] if self.unread else _NONE)[0]

    def samples(self) -> list[Sample]:
        """Each poll's :class:`~pymb.store.Sample`, in order."""
        return [self.sample(j) for j in range(len(self.sources))]


class _View(Mapping[str, Any]):
    """A sample's values or states, decoded when first read."""

    __slots__ = ()

    @abstractmethod
    def _map(self) -> dict[str, Any]:
        """The decoded dict this view shows."""

    def __getitem__(self, key: str) -> Any:
        return self._map()[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._map())

    def __len__(self) -> int:
        return len(self._map())

    def __repr__(self) -> str:
        return repr(self._map())


class _Values(_View):
    """A sample's values; it decodes them with their states on first use.
    Made by :func:`poll_sample`, which fills in its slots: the group's
    decoder, its registers, the items not read, and what was decoded
    (None until then)."""

    __slots__ = ("got", "how", "regs", "unread")
    how: GroupDecode
    regs: array[int]
    unread: frozenset[int]
    got: tuple[dict[str, Value], dict[str, Any]] | None

    def decoded(self, which: int) -> dict[str, Any]:
        """The values (0) or the states (1)."""
        got = self.got
        if got is None:
            got = self.got = self.how.decode(self.regs, self.unread)
        return got[which]

    def _map(self) -> dict[str, Any]:
        return self.decoded(0)


class _States(_View):
    """A sample's states, decoded with its values (``source``; the states
    point at the values, not back: a poll's records are freed by their
    reference counts, not by the garbage collector)."""

    __slots__ = ("source",)
    source: _Values

    def _map(self) -> dict[str, Any]:
        return self.source.decoded(1)


class _ReadingFill:
    """A poll's :class:`MapReading` while :func:`poll_sample` fills it in
    (then it is made one: the same layout, an instance dict)."""

    map: Any
    group: str | None
    values: _Values
    states: _States
    registers: array[int]
    unsupported: tuple[str, ...]
    wire: bytes


class _SampleFill:
    """A poll's :class:`Sample` while :func:`poll_sample` fills it in."""

    device: DeviceInfo
    time_utc: float
    monotonic: float
    data: MapReading


_SWAP = sys.byteorder == "little"
_NONE: frozenset[int] = frozenset()
_new = object.__new__
_set = object.__setattr__


def poll_sample(info: DeviceInfo, time_utc: float, monotonic: float, how: GroupDecode,
                image: bytes, unread: frozenset[int] = _NONE) -> tuple[Sample, MapReading]:
    """The :class:`Sample` of one poll of ``info`` and its data: a
    :class:`MapReading` of the registers of ``image`` (big-endian, as on the
    wire), values and states decoded on first use.

    A logger makes these records a poll: each is filled in as a plain
    object, then made what it is (``__class__``: the same layout), where
    their own constructors would each cost a Python call and an instance
    dict made at once (about 1,000 instructions a record more, callgrind);
    the views' slots are filled in from here too."""
    regs = array("H", image)
    if _SWAP:
        regs.byteswap()
    values: _Values = _new(_Values)
    values.how = how
    values.regs = regs
    values.unread = unread
    values.got = None
    states: _States = _new(_States)
    states.source = values
    r: Any = _new(_ReadingFill)
    r.map = how.map
    r.group = how.group
    r.values = values
    r.states = states
    r.registers = regs
    r.unsupported = how.unsupported(unread) if unread else ()
    r.wire = image
    r.__class__ = MapReading
    s: Any = _new(_SampleFill)
    s.device = info
    s.time_utc = time_utc
    s.monotonic = monotonic
    s.data = r
    s.__class__ = Sample
    return s, r


def _check_fills() -> None:
    """Each fill (and :meth:`PollBlock.of`) sets exactly its record's fields
    (checked at import: a field added to a record and not here fails at
    once, not at its first use)."""
    for fill, record in ((_ReadingFill, MapReading), (_SampleFill, Sample)):
        want = [f.name for f in fields(record)]
        if list(fill.__annotations__) != want:
            raise AssertionError(f"{fill.__name__} fills {list(fill.__annotations__)}, "
                                 f"{record.__name__} has {want}")
    made = PollBlock.of(0.0, 0.0, [], [], [], b"")
    if list(vars(made)) != [f.name for f in fields(PollBlock)]:
        raise AssertionError(f"PollBlock.of fills {list(vars(made))}")


_check_fills()
