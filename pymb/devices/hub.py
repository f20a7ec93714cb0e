"""The 100-channel sensor hub ([HUB] RS485 Modbus Communication Protocol V1.5).

``SensorHub`` is a typed view of the hub's map (``pymb.maps.builtin("hub")``)
read by a :class:`~pymb.devices.MapDevice`: ``read_all()`` reads registers
31..730 in the fewest requests the 255-byte frame allows (6), in one C call
with the GIL released, and the map's C decoder decodes them: no Python object
per register. Results are views over one float64 array and one uint8 state
array, which numpy takes without a copy (``numpy.asarray(reading.temperature_c)``).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import threading
import time
from array import array
from collections.abc import Callable, Iterable, Sequence
from typing import Any, cast

from pymb import maps
from pymb.client import Client
from pymb.devices.hubreading import (
    ALL_BLOCKS,
    BLOCKS,
    CHANNELS,
    HUB_REGISTERS,
    HubChannel,
    HubReading,
    State,
    block_index,
    check_channels,
    humidity_in_other_unit,
)
from pymb.devices.mapdevice import MapDevice, check_seconds
from pymb.devices.mapreading import Blocks
from pymb.errors import DeviceBusy, DeviceFailure, InvalidArgument
from pymb.maps import Buffers, Decoder, Map
from pymb.maps.device_plan import map_planner
from pymb.maps.planner import ReadPlan

__all__ = ["ALL_BLOCKS", "HubChannel", "HubReading", "SensorHub", "State", "busy_error",
           "decode_hub", "full_sweep_spans", "hub_device", "units"]

_N = HUB_REGISTERS  # 700 registers, 31..730
_FIRST = BLOCKS[0].address  # register 31: channel 1's temperature
_DEVICE = maps.builtin("hub").device  # addresses, default address


@functools.lru_cache(maxsize=64)
def _uniform_tenths(tenths: int, channels: int) -> bytes:
    return bytes([tenths]) * channels


def _tenths(humidity_unit: float | Sequence[float], channels: int) -> bytes:
    def one(u: float) -> int:
        if u == 1:
            return 0
        if isinstance(u, (int, float)) and math.isclose(u, 0.1):
            return 1
        raise InvalidArgument(f"humidity unit must be 1 or 0.1 (%), got {u!r}")

    if isinstance(humidity_unit, (int, float)):
        return _uniform_tenths(one(humidity_unit), channels)
    try:
        units = list(humidity_unit)
    except TypeError:
        raise InvalidArgument(f"humidity unit must be 1 or 0.1 (%), or a list of them, "
                              f"got {humidity_unit!r}") from None
    if len(units) != channels:
        raise InvalidArgument(f"{len(units)} humidity units given for {channels} channels")
    return bytes(one(u) for u in units)


def _names(blocks: Iterable[str] | None) -> tuple[str, ...] | None:
    """Block names as given (a copy), each checked; a lone string is refused
    (it would be read letter by letter)."""
    if blocks is None:
        return None
    if isinstance(blocks, str):
        raise InvalidArgument(f"blocks is a list of block names, e.g. [{blocks!r}]")
    try:
        names = tuple(blocks)
    except TypeError:
        raise InvalidArgument(f"blocks is a list of block names, got {blocks!r}") from None
    for name in names:
        block_index(name)  # an unknown name is an InvalidArgument naming the blocks
    return names


def _numbers(channels: Iterable[int] | None) -> tuple[int, ...] | None:
    """Channel numbers as given (a copy); each is checked against the hub's."""
    if channels is None:
        return None
    try:
        return tuple(channels)
    except TypeError:
        raise InvalidArgument(
            f"channels is a list of channel numbers, e.g. range(1, 13), got {channels!r}"
        ) from None


def full_sweep_spans(channels: int = CHANNELS) -> list[tuple[int, int]]:
    """The requests (address, count) of a sweep of every block of ``channels``
    channels as the hub's map plans them (a request of at most 125
    registers; whole blocks merge when every channel is read): the plan the
    benchmark's contenders and the logger's wire-time figure use."""
    return list(_sweep_plan(check_channels(channels)).spans)


@functools.lru_cache(maxsize=128)
def _sweep_plan(channels: int) -> ReadPlan:
    return map_planner(_hub_map(channels, 0.1))[0].plan()


@functools.lru_cache(maxsize=16)
def _hub_map(channels: int, unit: float) -> Map:
    """The hub's map for ``channels`` channels of humidity in ``unit`` %, as
    the facade reads it: the client's reply timeout (the facade has always
    used it), and blocks the firmware lacks skipped until the next
    connection (not retried on a timer)."""
    m = maps.builtin("hub").configure({"channels": channels, "humidity_unit": unit})
    return dataclasses.replace(m, timing=dataclasses.replace(
        m.timing, response_timeout=None, offline_retry=math.inf))


@functools.lru_cache(maxsize=8)
def _decoder(channels: int, unit: float) -> Decoder:
    """The map decoder of every block of ``channels`` channels, registers 31..."""
    m = _hub_map(channels, unit)
    return Decoder(m, [b.name for b in BLOCKS])


@functools.lru_cache(maxsize=8)
def _decoding(channels: int, unit: float) -> tuple[array[int], Callable[[], int], Buffers]:
    """:func:`_decoder`'s decode of one registers array bound once: the
    array, the call that decodes it into the buffers, the buffers."""
    dec = _decoder(channels, unit)
    shared = array("H", bytes(2 * _N))
    b = dec.new_buffers()
    return shared, dec.bind(shared, b), b


def units(humidity_unit: float | Sequence[float], channels: int) -> tuple[float, bytes]:
    """The humidity unit the map decodes with (the channels' most common)
    and, per channel, 1 where the channel's unit is the other one."""
    if type(humidity_unit) is float or type(humidity_unit) is int:
        return _one_unit(humidity_unit, channels)
    return _units(humidity_unit, channels)


@functools.lru_cache(maxsize=16)
def _one_unit(humidity_unit: float, channels: int) -> tuple[float, bytes]:
    return _units(humidity_unit, channels)


def _units(humidity_unit: float | Sequence[float], channels: int) -> tuple[float, bytes]:
    tenths = _tenths(humidity_unit, channels)
    ones = tenths.count(0)
    if ones > channels - ones:  # the channels in tenths are the other ones
        return 1.0, tenths
    return 0.1, tenths.translate(_FLIP)


_FLIP = bytes([1, 0]) + bytes(254)  # tenths -> 1 where a channel's unit is 1 %


def _other_units(r: HubReading, unit: float, other: bytes) -> None:
    """Channel humidity of the channels whose unit is not ``unit`` (1 in
    ``other``), decoded again from the raw registers."""
    humidity_in_other_unit(r.registers, r.values, r.raw_states, r.channels, unit, other)


def blocks_in_other_units(b: Blocks, registers: Sequence[int], unit: float,
                          other: bytes) -> None:
    """:func:`humidity_in_other_unit` on a hub map reading's :class:`Blocks`
    (the sweep reader's, the store's), if it holds the humidity."""
    at = b.index.get("humidity_pct")
    if at is not None and 1 in other:
        humidity_in_other_unit(registers, b.values, b.states, at, unit, other)


_DECODING = threading.Lock()


def decode_hub(registers: Any, humidity_unit: float | Sequence[float] = 0.1, *,
               channels: int = CHANNELS, unsupported: Iterable[str] = ()) -> HubReading:
    """Decode raw registers 31..730 (700 of them, any uint16 buffer or a
    sequence of ints) into a :class:`HubReading`, with no I/O: the hub's map
    decoder, the one the facade reads with.

    ``unsupported`` names blocks to mark as missing from the firmware.
    """
    regs: array[int]
    if type(registers) is array and registers.typecode == "H":
        regs = registers
    else:
        try:
            mv = memoryview(registers)
            as_u16 = mv.itemsize == 2
        except TypeError:
            as_u16 = False
        regs = array("H", mv.cast("B").tobytes()) if as_u16 else array("H", registers)
    if len(regs) != _N:
        raise InvalidArgument(f"decode_hub needs the {_N} registers 31..730, got {len(regs)}")
    mask = 0
    for name in unsupported:
        mask |= 1 << block_index(name)
    t = type(humidity_unit)  # (one unit for all: the decoding made ready, found at once)
    ready = _READY.get((channels, humidity_unit)) if type(channels) is int and (
        t is float or t is int) else None
    shared, run, b, unit, other = ready or _ready(channels, humidity_unit)
    with _DECODING:  # the decoder's arrays are shared
        shared[:] = regs
        run()
        values, states = b.values[:], b.states[:]
    # (the reading of arrays already made, taken, not copied: __init__'s fields, no call)
    r: HubReading = object.__new__(HubReading)
    r.channels, r.registers, r.values, r.raw_states = channels, regs, values, states
    r.unsupported_mask, r.time, r.monotonic = mask, 0.0, 0.0
    if other:
        _other_units(r, unit, other)
    if mask:
        _mark_blocks(r, mask, State.UNSUPPORTED)
    return r


_Ready = tuple["array[int]", Callable[[], int], Buffers, float, bytes]
_READY: dict[tuple[Any, Any], _Ready] = {}  #: (channels, one unit) -> its _ready()


def _ready(channels: int, humidity_unit: float | Sequence[float]) -> _Ready:
    """:func:`_decoding` of ``channels`` (checked) channels of humidity in
    ``humidity_unit``, with the unit the map decodes with and the channels
    in the other unit (empty: none); kept when the unit is one for all."""
    if channels != CHANNELS:
        channels = check_channels(channels)
    unit, other = units(humidity_unit, channels)
    ready = (*_decoding(channels, unit), unit, other if 1 in other else b"")
    if type(humidity_unit) in (float, int) and len(_READY) < 64:
        _READY[(channels, humidity_unit)] = ready
    return ready


def _mark_blocks(r: HubReading, mask: int, state: State) -> None:
    """NaN and ``state`` for every channel of the blocks in ``mask``."""
    c = r.channels
    nan, fill = _nans(c), bytes([state]) * c
    for i in range(len(BLOCKS)):
        if mask >> i & 1:
            r.values[i * c:(i + 1) * c] = nan
            r.raw_states[i * c:(i + 1) * c] = array("B", fill)


@functools.lru_cache(maxsize=128)
def _nans(channels: int) -> array[float]:
    return array("d", [math.nan]) * channels


def hub_device(client: Client, address: int, channels: int = CHANNELS, unit: float = 0.1, *,
               busy_retries: int = 3, busy_backoff: float = 0.02,
               turnaround: float = 0.005) -> MapDevice:
    """The :class:`~pymb.devices.MapDevice` a hub of ``channels`` channels
    (humidity in ``unit`` %) is read with: its map with the client's reply
    timeout, a busy hub (code 04) asked again ``busy_retries`` times, and
    the firmware rule: a block the firmware lacks answers 02 whole, and is
    skipped until the client reconnects."""
    dev = MapDevice(client, _hub_map(channels, unit), address, busy_retries=busy_retries,
                    busy_backoff=busy_backoff, plan_turnaround=turnaround, split_on=(2,))
    # [HUB] 3 / [NOTES]: a firmware has a block whole or answers 02 for it
    dev.planner.whole_points = True
    return dev


def busy_error(e: DeviceFailure, retries: int) -> DeviceBusy:
    """[HUB] 2.3.2.3: code 04 means busy, and the ``retries`` are used up."""
    return DeviceBusy(
        f"{e} (the sensor hub's code 04 means busy; gave up after "
        f"{retries} retries)",
        code=e.code, slave=e.slave, function=e.function, address=e.address,
        count=e.count, port=e.port, response=e.response)


class SensorHub:
    """The sensor hub at ``address`` (1..255) on ``client``: a typed view of
    the hub's map (``pymb.maps.builtin("hub")``) read by a
    :class:`~pymb.devices.MapDevice`.

    ``channels``: how many channels the hub has (50 for firmware V1.07 and
    below). ``humidity_unit``: 1 or 0.1 (%), for all channels or one per
    channel: the data does not say, it is the sensors' configuration.
    ``busy_retries`` / ``busy_backoff``: the hub answers exception 04 when
    busy; pymb waits ``busy_backoff`` seconds (doubling) and asks again up to
    ``busy_retries`` times before raising :class:`~pymb.DeviceBusy`.
    ``turnaround``: the hub's typical answer delay, for the read planner.

    Blocks the firmware lacks (it answers exception 02) are remembered and
    skipped; pymb probes them again after the client reconnects.
    """

    def __init__(self, client: Client, address: int = _DEVICE.default_address,
                 channels: int = CHANNELS, humidity_unit: float | Sequence[float] = 0.1,
                 *, busy_retries: int = 3, busy_backoff: float = 0.02,
                 turnaround: float = 0.005) -> None:
        low, high = _DEVICE.addresses
        if isinstance(address, bool) or not isinstance(address, int) or not (
            low <= address <= high
        ):
            raise InvalidArgument(f"hub address must be {low}..{high}, got {address!r}")
        if not isinstance(client, Client):
            raise InvalidArgument(f"a SensorHub needs a pymb client, got {client!r}")
        check_seconds("turnaround", turnaround)
        self.client = client
        self.address = address
        self.channels = check_channels(channels)
        self.turnaround = turnaround
        self._busy_retries = busy_retries
        self._unit, self._other = units(humidity_unit, channels)
        self._mixed = any(self._other)
        # busy_retries and busy_backoff: the MapDevice checks them
        self.device = hub_device(client, address, self.channels, self._unit,
                                 busy_retries=busy_retries, busy_backoff=busy_backoff,
                                 turnaround=turnaround)
        self._lock = threading.Lock()  # one read of this hub at a time (shared buffers)
        self._planner = self.device.planner
        self._version = -1  # the planner's version self._mask is of
        #: the reading read_all(into=) decodes into, the registers its decode
        #: call is bound to, that call, and the buffers it writes (which must
        #: live as long as the call)
        self._bound: tuple[HubReading, array[int], Callable[[], int], Buffers] | None = None
        self._refused = False  # the planner knows points the hub refused
        self._refused_channels: tuple[int, ...] = ()  # ... those outside whole blocks
        self._mask = 0
        # per block, its planner items (a block the firmware lacks: all refused)
        self._items = tuple(frozenset(range(i * self.channels, (i + 1) * self.channels))
                            for i in range(len(BLOCKS)))

    # -- firmware knowledge -------------------------------------------------------

    def _unsupported_mask(self) -> int:
        """The blocks the device refused, as the planner knows them."""
        planner = self._planner
        if planner.version != self._version:
            gone = planner.unsupported
            mask = 0
            if gone:
                for i, items in enumerate(self._items):
                    if items <= gone:
                        mask |= 1 << i
            c = self.channels
            self._refused = bool(gone)
            self._refused_channels = tuple(sorted(k for k in gone if not mask >> (k // c) & 1))
            self._mask, self._version = mask, planner.version
        return self._mask

    @property
    def unsupported(self) -> frozenset[str]:
        """Blocks this hub's firmware lacks, as far as seen so far."""
        m = self._unsupported_mask()
        return frozenset(b.name for i, b in enumerate(BLOCKS) if m >> i & 1)

    def forget_firmware(self) -> None:
        """Forget which blocks are missing: the next read probes them all."""
        with self._lock:
            self._planner.forget()

    # -- planning -----------------------------------------------------------------

    def plan(self, blocks: Iterable[str] | None = None,
             channels: Iterable[int] | None = None) -> ReadPlan:
        """The requests a read of these blocks and channels would make, with
        their predicted wire time at the client's baud rate (see
        :meth:`ReadPlan.explain`)."""
        names, chans = _names(blocks), self._numbers(channels)
        if names is None:
            return self.device.plan("sweep", channels=chans)
        return self.device.plan(None, *names, channels=chans)

    def _numbers(self, channels: Iterable[int] | None) -> tuple[int, ...] | None:
        chans = _numbers(channels)
        if chans is None:
            return None
        for c in chans:
            if isinstance(c, bool) or not isinstance(c, int) or not 1 <= c <= self.channels:
                raise InvalidArgument(f"channel must be 1..{self.channels}, got {c!r}")
        return None if len(set(chans)) == self.channels else tuple(sorted(set(chans)))

    # -- reads --------------------------------------------------------------------

    def read_all(self, *, into: HubReading | None = None) -> HubReading:
        """Every block of every channel; blocks the firmware lacks are marked
        :attr:`State.UNSUPPORTED`. ``into`` reuses an earlier reading's arrays."""
        r = into
        if not isinstance(r, HubReading) or r.channels != self.channels:
            return self.read(into=into)  # a new reading, or the error
        # Every block into r: the map decoder writes straight into its arrays
        # (bound once per reading: a poller's steady state allocates nothing).
        # A poller's hot path, in this one frame: the lock acquired and
        # released, not a with block.
        lock = self._lock
        lock.acquire()
        try:
            try:
                ((dec, regs),) = self.device.fetch(group="sweep")
            except DeviceFailure as e:
                raise self._busy(e) from None
            bound = self._bound
            if bound is None or bound[0] is not r or bound[1] is not regs:
                buffers = Buffers(dec.slots, 0, values=r.values, states=r.raw_states)
                self._bound = bound = (r, regs, dec.bind(regs, buffers), buffers)
            bound[2]()
            r.registers[:len(regs)] = regs
            mask = self._mask if self._planner.version == self._version else (
                self._unsupported_mask())
            if self._refused:
                self._mark_refused(r, mask)
        finally:
            lock.release()
        if self._mixed:
            _other_units(r, self._unit, self._other)
        r.unsupported_mask = mask
        r.time = time.time()
        r.monotonic = time.monotonic()
        return r

    def read(self, blocks: Iterable[str] | None = None, channels: Iterable[int] | None = None,
             *, into: HubReading | None = None) -> HubReading:
        """Some blocks (by name, e.g. ``["temperature_c"]``) and/or channels
        (1-based), in the planned requests; the rest is :attr:`State.NOT_READ`."""
        if into is not None and not isinstance(into, HubReading):
            raise InvalidArgument(f"into must be a HubReading, got {into!r}")
        names = _names(blocks)
        chans = None if channels is None else self._numbers(channels)
        if names is None and chans is None and into is not None and \
                into.channels == self.channels:
            return self.read_all(into=into)
        r = into if into is not None and into.channels == self.channels else HubReading(
            self.channels)
        with self._lock:
            try:
                if names is None:
                    decs = self.device.read_into(group="sweep", channels=chans)
                else:
                    decs = self.device.read_into(*names, channels=chans)
            except DeviceFailure as e:
                raise self._busy(e) from None
            self._copy(decs[0], names, r)
            mask = self._unsupported_mask()
        if self._mixed:
            _other_units(r, self._unit, self._other)
        r.unsupported_mask = mask
        r.time = time.time()
        r.monotonic = time.monotonic()
        return r

    def _mark_refused(self, r: HubReading, mask: int) -> None:
        """NaN and ``unsupported`` where the hub refused: whole blocks, then
        any other channel the planner knows it refused."""
        if mask:
            _mark_blocks(r, mask, State.UNSUPPORTED)
        for k in self._refused_channels:
            r.values[k] = math.nan
            r.raw_states[k] = State.UNSUPPORTED

    def _busy(self, e: DeviceFailure) -> DeviceBusy:
        return busy_error(e, self._busy_retries)

    def _copy(self, dec: Decoder, names: tuple[str, ...] | None, r: HubReading) -> None:
        """The decoder's values, states and registers into ``r``'s arrays."""
        b = dec.buffers
        regs = cast("array[int]", b.registers)  # the array read_into decoded
        at = dec.address - _FIRST
        r.registers[at:at + len(regs)] = regs
        if names is None:  # every block: the decoder's arrays are the reading's layout
            r.values[:] = b.values
            r.raw_states[:] = b.states
            return
        c = self.channels
        r.values[:] = _nans(c) * len(BLOCKS)
        r.raw_states[:] = array("B", bytes([State.NOT_READ]) * (c * len(BLOCKS)))
        for name in dict.fromkeys(names):
            i, slot = block_index(name), dec.slot(name)
            r.values[i * c:(i + 1) * c] = b.values[slot:slot + c]
            r.raw_states[i * c:(i + 1) * c] = b.states[slot:slot + c]
