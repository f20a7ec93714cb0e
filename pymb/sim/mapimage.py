"""The registers a map declares, as a simulated device holds them: :class:`MapImage`.

One ``array('H')`` image per table, which registers answer at the device's
firmware (a point whose ``min_firmware`` is above it is absent; reading it
answers exception 02), and a point's value or raw number put in or read out
of its registers by name. :class:`~pymb.sim.mapsim.MapSimDevice` adds the
values and the requests on top.
"""

from __future__ import annotations

import struct
from array import array
from collections.abc import Iterable
from typing import ClassVar

from pymb.errors import InvalidArgument
from pymb.maps import Map, MapError, Point
from pymb.maps.codec import _pattern, _to_regs, encode
from pymb.maps.model import check_address
from pymb.maps.types import SF_RANGE, TABLE_FUNCTIONS, permutation
from pymb.sim.base import Device, _locked, parse_firmware
from pymb.sim.clock import SimClock

__all__ = ["TABLES", "MapImage"]

#: the tables by their read function code
TABLES = {fc: t for t, fc in TABLE_FUNCTIONS.items()}


def _swaps(p: Point) -> bool:
    """The order of text ``p`` swaps the two bytes of each register (BA, BADC, DCBA)."""
    return bool(p.order) and permutation(p.order)[0] % 2 == 1


def _swap_pairs(data: bytes) -> bytes:
    """``data`` with the two bytes of each register swapped."""
    out = bytearray(data)
    out[0::2], out[1::2] = data[1::2], data[0::2]
    return bytes(out)


class MapImage(Device):
    """The registers of map ``m``'s device at ``address``; the firmware is
    set by the subclass (every point is there until then)."""

    #: the map's ``readable`` ranges answer (zeros) besides its points
    answers_readable: ClassVar[bool] = True

    def __init__(self, m: Map, address: int | None, *, baud: int, seed: int,
                 clock: SimClock | None) -> None:
        super().__init__(check_address(m, address), baud=baud, seed=seed, clock=clock)
        self.map = m
        self.kind = m.id  # type: ignore[misc]
        self._images = {t: array("H", bytes(2 * 0x10000)) for t in TABLES.values()}
        self._have = {t: bytearray(0x10000) for t in TABLES.values()}
        #: (name, channel) -> (point, address), for _put_raw
        self._where: dict[tuple[str, int], tuple[Point, int]] = {}
        self._firmware = ""

    @property
    def firmware(self) -> str:
        """The firmware version; setting it adds or removes the points whose
        ``min_firmware`` it reaches or not."""
        return self._firmware

    @firmware.setter
    @_locked
    def firmware(self, version: str) -> None:
        parse_firmware(version)  # refuses what does not look like 2.19
        self._firmware = version.strip().lstrip("vV")
        self._build_have()

    def _build_have(self) -> None:
        """Which registers answer: the points the firmware has (and ``readable``)."""
        have = {t: bytearray(0x10000) for t in TABLES.values()}
        if self.answers_readable:
            for t, ranges in self.map.limits.readable.items():
                for lo, hi in ranges:
                    have[t][lo:hi + 1] = b"\x01" * (hi + 1 - lo)
        for p in self.map.points.values():
            for c in range(1, self._channels_of(p) + 1):
                a = p.address_of(c)
                have[p.table][a:a + p.count] = b"\x01" * p.count
        self._have = have

    def _channels_of(self, p: Point) -> int:
        """How many channels of ``p`` the device has (0: none) at its firmware."""
        if self._firmware and p.min_firmware and \
                parse_firmware(p.min_firmware) > parse_firmware(self._firmware):
            return 0
        return p.channels

    @property
    def channels(self) -> int:
        """The most channels any block has at the firmware (1 for a map
        without blocks, 0 when the firmware has no point)."""
        return max((self._channels_of(p) for p in self.map.points.values()), default=0)

    def supports(self, name: str) -> bool:
        """True when the firmware has point (or block) ``name``."""
        return name in self.map.points and self._channels_of(self.map.points[name]) > 0

    def _cis(self, channel: int | Iterable[int] | None) -> list[int]:
        """Channel indexes (0-based) of ``channel`` (1-based, several, or
        None for every channel of the map's blocks)."""
        n = max((p.channels for p in self.map.points.values()), default=1)
        chans = list(range(1, n + 1) if channel is None else
                     [channel] if isinstance(channel, int) else channel)
        bad = [c for c in chans if not 1 <= c <= n]
        if bad:
            raise InvalidArgument(f"channel must be 1..{n}, got {bad[0]!r}")
        return [c - 1 for c in chans]

    def _point(self, name: str, channel: int = 1) -> tuple[Point, int]:
        """The point ``name`` and the address of its ``channel``; unknown
        ones are an :class:`~pymb.InvalidArgument` naming the closest."""
        try:
            p = self.map.point(name)
            return p, p.address_of(channel)
        except MapError as e:
            raise InvalidArgument(str(e)) from None

    def _now(self) -> None:
        """Bring every value to the clock's time (a subclass's values)."""

    @_locked
    def raw(self, name: str, channel: int = 1) -> int:
        """The registers of point ``name`` (its ``channel``) as a read now
        returns them, as one unsigned number (the point's order applied)."""
        p, a = self._point(name, channel)
        self._now()
        return self._raw(p, a)

    def _raw(self, p: Point, a: int) -> int:
        regs = self._images[p.table][a:a + p.count]
        if len(p.order) == 2 * p.count:
            return _pattern(p, regs)
        # text and raw: the registers in their order, each one's two bytes as the order says
        wire = struct.pack(f">{p.count}H", *regs)
        return int.from_bytes(_swap_pairs(wire) if _swaps(p) else wire, "big")

    @_locked
    def registers(self, address: int | None = None, count: int | None = None,
                  table: str | None = None) -> array[int]:
        """The register image of ``table`` (default the map's) now, whatever
        the firmware lacks included: ``count`` registers from ``address``;
        by default those from the table's first point to its last."""
        table = self.map.device.table if table is None else table
        if table not in self._images:
            raise InvalidArgument(f"table must be one of {', '.join(self._images)}, got {table!r}")
        ends = [(p.address, p.address_of(p.channels) + p.count)
                for p in self.map.points.values() if p.table == table]
        first = min((a for a, _ in ends), default=0)
        address = first if address is None else address
        count = max((e for _, e in ends), default=first) - first if count is None else count
        self._now()
        return self._images[table][address:address + count]

    @_locked
    def set_identity(self, /, **values: int) -> None:
        """Set points of the map's ``identity`` group by name to raw values
        (``serial_number=...``)."""
        for name, value in values.items():
            if self._point(name)[0].group != "identity":
                raise InvalidArgument(f"{name} is not an identity point")
            self._put_raw(name, value)

    def _put_raw(self, name: str, raw: int, channel: int = 1) -> None:
        """Store ``raw`` (an unsigned number, as :meth:`raw` gives) in point ``name``."""
        where = self._where.get((name, channel))
        if where is None:
            where = self._where[(name, channel)] = self._point(name, channel)
        p, a = where
        img = self._images[p.table]
        raw &= (1 << 16 * p.count) - 1
        if p.count == 1 and p.order == "AB":
            img[a] = raw
        elif len(p.order) == 2 * p.count:
            img[a:a + p.count] = array("H", _to_regs(p, raw))
        else:  # text and raw: as _raw reads them
            wire = raw.to_bytes(2 * p.count, "big")
            wire = _swap_pairs(wire) if _swaps(p) else wire
            img[a:a + p.count] = array("H", struct.unpack(f">{p.count}H", wire))

    def _put(self, p: Point, channel: int, value: object) -> None:
        """Encode ``value`` into ``p``'s registers (of its ``channel``)."""
        a = p.address_of(channel)
        img = self._images[p.table]
        current = list(img[a:a + p.count])
        sf = self._sf_of(p)
        if p.scale_from is not None and sf is None:
            return  # the scale factor says "not implemented": the raw value stays
        regs = encode(p, value, current=current, check_access=False, sf=sf)
        img[a:a + len(regs)] = array("H", regs)

    def _sf_of(self, p: Point) -> int | None:
        """The scale factor a ``scale_from`` point has now (None: none, or
        not implemented)."""
        if p.scale_from is None:
            return None
        q = self.map.points[p.scale_from]
        v = self.map.decode(q.name, self._images[q.table][q.address:q.address + 1])
        return v if isinstance(v, int) and SF_RANGE[0] <= v <= SF_RANGE[1] else None
