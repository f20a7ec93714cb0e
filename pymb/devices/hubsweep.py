"""The sensor hub read as a map device: :class:`SweepReader` reads its map's
groups, or some blocks and channels, as :class:`~pymb.devices.mapreading.MapReading`
with the hub's own rules (:func:`~pymb.devices.hub.hub_device`: the
firmware's missing blocks, a busy hub; a humidity unit per channel).
``pymb read`` and ``pymb watch`` read a hub with it, and the logger a hub
whose channels' humidity units differ, or any hub logged ``--on-change``
(else it polls the hub as its map's group: the registers, as
:attr:`SweepReader.device` fetches them)."""

from __future__ import annotations

import math
from array import array
from collections.abc import Sequence
from typing import Any

from pymb.client import Client
from pymb.devices.hub import blocks_in_other_units, busy_error, hub_device, units
from pymb.devices.hubreading import BLOCKS, CHANNELS
from pymb.devices.mapdevice import MapDevice
from pymb.devices.mapreading import Blocks, MapReading
from pymb.errors import DeviceBusy, DeviceFailure
from pymb.maps.types import STATES

__all__ = ["SweepReader"]

_FIRST = BLOCKS[0].address  # register 31: channel 1's temperature
_BUSY_RETRIES = 3
_UNSUPPORTED = STATES.index("unsupported")  #: its code in the decoder's states


class SweepReader:
    """The hub at ``address`` on ``client``, of ``channels`` channels with
    humidity in ``humidity_unit`` % (one for all, or one a channel): its
    :attr:`device` and, called with a group of its map, one read of it."""

    def __init__(self, client: Client, address: int, channels: int,
                 humidity_unit: float | Sequence[float]) -> None:
        self.unit, self.other = units(humidity_unit, channels)
        self.channels = channels
        self.device: MapDevice = hub_device(client, address, channels, self.unit,
                                            busy_retries=_BUSY_RETRIES)
        #: some channel's humidity in another unit than the map's: a reading's
        #: values are the hub's own decode (:func:`blocks_in_other_units`), not
        #: its map's alone
        self.mixed = any(self.other)
        self._index: dict[str | None, dict[str, int]] = {}  # by group: the blocks' slots

    def busy(self, e: DeviceFailure) -> DeviceBusy:
        """What a read raises when the hub answered ``e`` (code 04: busy)
        through every retry."""
        return busy_error(e, _BUSY_RETRIES)

    def __call__(self, group: str | None) -> MapReading:
        """Every block of ``group`` (the sweep), its values and states kept
        as the decoder made them (:class:`~pymb.devices.mapreading.Blocks`)."""
        try:
            (d,) = self.device.read_into(group=group)
        except DeviceFailure as e:
            raise self.busy(e) from None
        b, c = d.buffers, self.channels
        index = self._index.get(group)
        if index is None:
            index = self._index[group] = {p.name: d.slot(p.name) for p in BLOCKS
                                          if p.name in self.device.map.points and
                                          (group is None or p.group == group)}
        names = tuple(index)
        blocks = Blocks(names, c, array("d", b.values), array("B", b.states), index)
        if self.mixed:
            blocks_in_other_units(blocks, b.registers, self.unit, self.other)
        # An int searched in bytes: one memchr, where a bytes searched in a slice
        # first fails as an int (a TypeError made and dropped) for every block.
        sts, at = blocks.states.tobytes(), blocks.index
        gone = () if _UNSUPPORTED not in sts else tuple(
            n for n in names if sts.find(_UNSUPPORTED, at[n], at[n] + c) >= 0)
        return MapReading(self.device.map, group, blocks.value_map(), blocks.state_map(),
                          array("H", b.registers), gone)

    def blocks(self, names: Sequence[str], channels: Sequence[int] | None) -> MapReading:
        """The blocks ``names`` (of ``channels`` only, 1-based, if given): every
        block is in the reading, those not read (and the channels not read)
        ``not_read``; ``unsupported`` names the blocks the firmware lacks, as
        far as seen so far."""
        names = tuple(names) or tuple(b.name for b in BLOCKS)
        try:
            decs = self.device.read_into(*names, channels=channels)
        except DeviceFailure as e:
            raise self.busy(e) from None
        c = self.channels
        values: dict[str, Any] = {b.name: [None] * c for b in BLOCKS}
        states: dict[str, Any] = {b.name: ["not_read"] * c for b in BLOCKS}
        regs = array("H", bytes(2 * CHANNELS * len(BLOCKS)))  # 31..730
        for d in decs:
            b = d.buffers
            got, sts = d.values(b), d.states(b)
            for n in dict.fromkeys(names):
                if n in got:
                    values[n], states[n] = got[n], sts[n]
            at = d.address - _FIRST
            regs[at:at + d.count] = array("H", b.registers)
        gone = self.device.planner.unsupported
        missing = tuple(b.name for i, b in enumerate(BLOCKS)
                        if gone and all(k in gone for k in range(i * c, (i + 1) * c)))
        if self.mixed:
            flat = Blocks(list(values), c, array("d"), array("B"))
            for n in flat.names:  # (the blocks as flat arrays, to decode again)
                flat.values.extend(math.nan if v is None else v for v in values[n])
                flat.states.extend(STATES.index(x) for x in states[n])
            blocks_in_other_units(flat, regs, self.unit, self.other)
            values.update(flat.value_map())
            states.update(flat.state_map())
        return MapReading(self.device.map, None, values, states, regs, missing)
