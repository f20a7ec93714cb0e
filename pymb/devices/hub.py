"""The 100-channel sensor hub ([HUB] RS485 Modbus Communication Protocol V1.5).

``SensorHub.read_all()`` reads registers 31..730 in the fewest requests the
255-byte frame allows (6) and decodes them in C, with the GIL released for
the whole sweep: no Python object per register. Results are views over one
float64 array and one uint8 state array, which numpy takes without a copy
(``numpy.asarray(reading.temperature_c)``).
"""

from __future__ import annotations

import functools
import math
import threading
import time
from array import array
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

from pymb import _native
from pymb.client import Client
from pymb.devices.maps import HUB
from pymb.errors import DeviceBusy, DeviceFailure, InvalidArgument
from pymb.maps.planner import Item, Known, Line, ReadPlan, plan_points
from pymb.wire import bits_per_char

__all__ = ["ALL_BLOCKS", "HubChannel", "HubReading", "SensorHub", "State", "decode_hub",
           "full_sweep_spans"]

_N = HUB.count  # 700 registers, 31..730
#: The block mask with every block set (``HubReading.unsupported_mask ==
#: ALL_BLOCKS``: the hub supplied no value at all).
ALL_BLOCKS = _native.HUB_ALL_BLOCKS
_ZERO_REGS = array("H", bytes(2 * _N))


#: Why a decoded value is (or is not) there: the C core's ``pymb_state``.
State = _native.State


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


_TENTHS_100 = _uniform_tenths(1, HUB.channels)


@functools.lru_cache(maxsize=128)
def _zeros(channels: int) -> tuple[array[float], array[int]]:
    return array("d", bytes(8 * 7 * channels)), array("B", bytes(7 * channels))


def _channels(channels: int) -> int:
    if isinstance(channels, bool) or not isinstance(channels, int) or not (
        1 <= channels <= HUB.channels
    ):
        raise InvalidArgument(f"channels must be 1..{HUB.channels}, got {channels!r}")
    return channels


@dataclass(frozen=True)
class HubChannel:
    """One channel's values (NaN where there is none) and their states."""

    channel: int
    temperature_c: float
    humidity_pct: float
    pressure_temperature_c: float
    pressure_kpa: float
    voltage_mv: float
    rssi_dbm: float
    temperature2_c: float
    states: dict[str, State]


class HubReading:
    """One read of the hub: seven float sequences of ``channels`` values
    (``temperature_c``, ``humidity_pct``, ``pressure_temperature_c``,
    ``pressure_kpa``, ``voltage_mv``, ``rssi_dbm``, ``temperature2_c``), NaN
    where there is no value, and why in :meth:`states` /:meth:`state`.

    ``registers`` keeps the raw registers 31..730 (lossless); ``values`` and
    ``raw_states`` are the whole block-major arrays. ``time`` (UTC, seconds)
    and ``monotonic`` say when the read finished.
    """

    __slots__ = ("channels", "monotonic", "raw_states", "registers", "time",
                 "unsupported_mask", "values")

    def __init__(self, channels: int, registers: array[int] | None = None) -> None:
        if channels != HUB.channels:
            _channels(channels)
        values, states = _zeros(channels)
        self.channels = channels
        self.registers = array("H", _ZERO_REGS) if registers is None else registers
        self.values = array("d", values)
        self.raw_states = array("B", states)
        self.unsupported_mask = 0
        self.time = 0.0
        self.monotonic = 0.0

    def _block(self, index: int) -> memoryview:
        c = self.channels
        return memoryview(self.values)[index * c:(index + 1) * c]

    @property
    def temperature_c(self) -> memoryview:
        """Channel temperatures, °C."""
        return self._block(0)

    @property
    def humidity_pct(self) -> memoryview:
        """Channel humidity, %."""
        return self._block(1)

    @property
    def pressure_temperature_c(self) -> memoryview:
        """Pressure sensors' temperatures, °C."""
        return self._block(2)

    @property
    def pressure_kpa(self) -> memoryview:
        """Pressures, kPa."""
        return self._block(3)

    @property
    def voltage_mv(self) -> memoryview:
        """Channel voltages, mV (firmware V2.19 and above)."""
        return self._block(4)

    @property
    def rssi_dbm(self) -> memoryview:
        """Channel RSSI, dBm (firmware V2.19 and above)."""
        return self._block(5)

    @property
    def temperature2_c(self) -> memoryview:
        """Second temperatures, °C (firmware V2.23 and above)."""
        return self._block(6)

    def states(self, name: str) -> memoryview:
        """The :class:`State` codes (uint8) of one quantity, per channel."""
        i = HUB.block(name).index
        c = self.channels
        return memoryview(self.raw_states)[i * c:(i + 1) * c]

    def state(self, name: str, channel: int) -> State:
        """The :class:`State` of one quantity of one channel (1-based)."""
        self._check(channel)
        return State(self.raw_states[HUB.block(name).index * self.channels + channel - 1])

    @property
    def unsupported(self) -> frozenset[str]:
        """Blocks this hub's firmware does not have."""
        return frozenset(b.name for b in HUB.blocks if self.unsupported_mask >> b.index & 1)

    def _check(self, channel: int) -> None:
        if isinstance(channel, bool) or not isinstance(channel, int) or not (
            1 <= channel <= self.channels
        ):
            raise InvalidArgument(f"channel must be 1..{self.channels}, got {channel!r}")

    def channel(self, n: int) -> HubChannel:
        """Channel ``n`` (1-based): its seven values and their states."""
        self._check(n)
        c, i = self.channels, n - 1
        v = self.values
        states = {b.name: State(self.raw_states[b.index * c + i]) for b in HUB.blocks}
        return HubChannel(n, v[i], v[c + i], v[2 * c + i], v[3 * c + i], v[4 * c + i],
                          v[5 * c + i], v[6 * c + i], states)

    def as_dict(self) -> dict[str, list[float | None]]:
        """Plain lists per quantity, None where there is no value (for JSON)."""
        return {
            b.name: [None if math.isnan(v) else v for v in self._block(b.index)]
            for b in HUB.blocks
        }

    def __repr__(self) -> str:
        return f"<HubReading {self.channels} channels, unsupported={sorted(self.unsupported)}>"


def _seconds_in(value: Any, high: float) -> bool:
    """``value`` is a number of seconds in 0..high."""
    return (not isinstance(value, bool) and isinstance(value, (int, float))
            and 0 <= value <= high)


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
        HUB.block(name)  # an unknown name is an InvalidArgument naming the blocks
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


def full_sweep_spans(channels: int = HUB.channels) -> list[tuple[int, int]]:
    """The requests (address, count) of a sweep of every block of ``channels``
    channels: the C core's plan (pymb_hub_plan_all), the one the benchmark's
    contenders and the logger's wire-time figure use."""
    return _native.hub_plan_all(0, _channels(channels))


def decode_hub(registers: Any, humidity_unit: float | Sequence[float] = 0.1, *,
               channels: int = HUB.channels, unsupported: Iterable[str] = ()) -> HubReading:
    """Decode raw registers 31..730 (700 of them, any uint16 buffer or a
    sequence of ints) into a :class:`HubReading`, with no I/O.

    ``unsupported`` names blocks to mark as missing from the firmware.
    """
    if channels != HUB.channels:
        channels = _channels(channels)
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
        mask |= 1 << HUB.block(name).index
    r = HubReading(channels, regs)
    tenths = _TENTHS_100 if humidity_unit == 0.1 and channels == HUB.channels else _tenths(
        humidity_unit, channels)
    _native.hub_decode(regs, channels, tenths, None, ALL_BLOCKS & ~mask, mask, r.values,
                       r.raw_states)
    r.unsupported_mask = mask
    return r


class SensorHub:
    """The sensor hub at ``address`` (1..255) on ``client``.

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

    def __init__(self, client: Client, address: int = HUB.default_address,
                 channels: int = HUB.channels, humidity_unit: float | Sequence[float] = 0.1,
                 *, busy_retries: int = 3, busy_backoff: float = 0.02,
                 turnaround: float = 0.005) -> None:
        low, high = HUB.addresses
        if isinstance(address, bool) or not isinstance(address, int) or not (
            low <= address <= high
        ):
            raise InvalidArgument(f"hub address must be {low}..{high}, got {address!r}")
        if not callable(getattr(client, "run_hub_sweep", None)):
            raise InvalidArgument(f"a SensorHub needs a pymb client, got {client!r}")
        if isinstance(busy_retries, bool) or not isinstance(busy_retries, int) or not (
                0 <= busy_retries <= 100):
            raise InvalidArgument(f"busy_retries must be 0..100, got {busy_retries!r}")
        if not _seconds_in(busy_backoff, 10):
            raise InvalidArgument(f"busy_backoff must be 0..10 s, got {busy_backoff!r}")
        if not _seconds_in(turnaround, 10):
            raise InvalidArgument(f"turnaround must be 0..10 s, got {turnaround!r}")
        self.client = client
        self.address = address
        self.channels = _channels(channels)
        self.turnaround = turnaround
        self._sweep = _native.HubSweep(address, self.channels, _tenths(humidity_unit, channels),
                                       busy_retries, busy_backoff)
        self._connections = -1
        self._lock = threading.Lock()  # one sweep of this hub at a time (shared C request)
        self._plans: dict[tuple[Any, ...], tuple[ReadPlan, bytes | None]] = {}
        self._current: tuple[Any, ...] | None = None  # (blocks, channels, unsupported) planned
        self._bound: HubReading | None = None  # the reading whose buffers the sweep holds
        self._keep: tuple[Any, ...] = ()  # ... and the cffi views that keep them valid

    # -- firmware knowledge -------------------------------------------------------

    @property
    def unsupported(self) -> frozenset[str]:
        """Blocks this hub's firmware lacks, as far as seen so far."""
        m = self._sweep.unsupported
        return frozenset(b.name for b in HUB.blocks if m >> b.index & 1)

    def forget_firmware(self) -> None:
        """Forget which blocks are missing: the next read probes them all."""
        with self._lock:  # not while a sweep (GIL released) may update it
            self._sweep.unsupported = 0
            self._current = None

    # -- planning -----------------------------------------------------------------

    def _baudrate(self) -> int:
        return int(getattr(self.client, "baudrate", HUB.default_baud))

    def _bits(self) -> int:
        c = self.client
        return bits_per_char(getattr(c, "parity", "N"), getattr(c, "stop_bits", 1),
                             getattr(c, "data_bits", 8))

    def _wanted(self, blocks: Sequence[str] | None,
                channels: Sequence[int] | None) -> tuple[list[int], bool]:
        chosen = list(HUB.blocks) if blocks is None else [HUB.block(b) for b in blocks]
        if channels is None:
            chans = list(range(1, self.channels + 1))
            full = blocks is None
        else:
            chans = sorted(set(channels))
            for c in chans:
                if isinstance(c, bool) or not isinstance(c, int) or not 1 <= c <= self.channels:
                    raise InvalidArgument(f"channel must be 1..{self.channels}, got {c!r}")
            full = blocks is None and len(chans) == self.channels
        skip = self._sweep.unsupported
        addresses = [b.address(c) for b in chosen if not skip >> b.index & 1 for c in chans]
        return addresses, full

    def _known(self) -> dict[str, Known]:
        """The registers this hub has: every channel of every block its
        firmware supports (a plan may read those it was not asked for)."""
        skip = self._sweep.unsupported
        return {"input": Known((b.address(1), b.address(1) + self.channels)
                               for b in HUB.blocks if not skip >> b.index & 1)}

    def plan(self, blocks: Iterable[str] | None = None,
             channels: Iterable[int] | None = None) -> ReadPlan:
        """The requests a read of these blocks and channels would make, with
        their predicted wire time at the client's baud rate (see
        :meth:`ReadPlan.explain`)."""
        return self._plan(blocks, channels)[0]

    def _plan(self, blocks: Iterable[str] | None,
              channels: Iterable[int] | None) -> tuple[ReadPlan, bytes | None]:
        key = (_names(blocks), _numbers(channels), self._sweep.unsupported, self._baudrate())
        cached = self._plans.get(key)
        if cached is not None:
            return cached
        addresses, full = self._wanted(key[0], key[1])
        items = [Item(str(a), "input", a) for a in addresses]
        plan = plan_points(items, Line(self._baudrate(), self._bits(), self.turnaround),
                           known=self._known())
        wanted: bytes | None = None
        if not full:
            bitmap = bytearray(_native.HUB_BITMAP_BYTES)
            for a in addresses:
                i = a - HUB.first
                bitmap[i // 8] |= 1 << (i % 8)
            wanted = bytes(bitmap)
        self._plans[key] = (plan, wanted)
        return plan, wanted

    # -- reads --------------------------------------------------------------------

    def read_all(self, *, into: HubReading | None = None) -> HubReading:
        """Every block of every channel; blocks the firmware lacks are marked
        :attr:`State.UNSUPPORTED`. ``into`` reuses an earlier reading's arrays."""
        return self.read(into=into)

    def read(self, blocks: Iterable[str] | None = None, channels: Iterable[int] | None = None,
             *, into: HubReading | None = None) -> HubReading:
        """Some blocks (by name, e.g. ``["temperature_c"]``) and/or channels
        (1-based), in the planned requests; the rest is :attr:`State.NOT_READ`."""
        # Plans are cached by these: copies, so the caller's lists may change.
        b, c = _names(blocks), _numbers(channels)
        if into is not None and not isinstance(into, HubReading):
            raise InvalidArgument(f"into must be a HubReading, got {into!r}")
        with self._lock:
            return self._read(b, c, into)

    def _read(self, blocks: Iterable[str] | None, channels: Iterable[int] | None,
              into: HubReading | None) -> HubReading:
        client = self.client
        if client.connections != self._connections:
            # A new connection may be a new device (or new firmware): probe again.
            self._connections = client.connections
            self._sweep.unsupported = 0
        # Steady state (the same read as last time, no firmware news): the
        # sweep struct already holds the plan, and (read_all(into=r) again)
        # r's buffers: nothing is allocated for them.
        current = self._current
        unsupported = self._sweep.unsupported
        if (current is None or current[0] != blocks or current[1] != channels
                or current[2] != unsupported):
            plan, wanted = self._plan(blocks, channels)
            self._sweep.set_plan(list(plan.spans), wanted)
            self._current = (blocks, channels, unsupported)
        r = into if into is not None and into.channels == self.channels else HubReading(
            self.channels)
        if r is not self._bound:
            self._keep = self._sweep.bind(r.registers, r.values, r.raw_states)
            self._bound = r
        try:
            client.run_hub_sweep(self._sweep)
        except DeviceFailure as e:
            # [HUB] 2.3.2.3: code 04 means busy, and the retries are used up.
            raise DeviceBusy(
                f"{e} (the sensor hub's code 04 means busy; gave up after "
                f"{self._sweep.request.options.busy_retries} retries)",
                code=e.code, slave=e.slave, function=e.function, address=e.address,
                count=e.count, port=e.port, response=e.response,
            ) from None
        finally:
            if r is not into:
                # A reading of its own goes to the caller: let go of its buffers.
                self._sweep.unbind()
                self._keep = ()
                self._bound = None
        # Blocks found missing in this sweep are skipped by the next plan.
        r.unsupported_mask = self._sweep.unsupported
        r.time = time.time()
        r.monotonic = time.monotonic()
        return r
