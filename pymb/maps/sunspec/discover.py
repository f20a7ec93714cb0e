"""Finding a SunSpec device's models: ``SunS`` at 40000, 0 or 50000, then
the chain of models (ID, L, L registers) up to the end marker (ID 0xFFFF).

Reads holding registers only, through any pymb client; each model's
registers are read whole once (in requests of at most 125 registers), since
the counts of some repeating groups are points of the model (``NPt``). A
request the device refuses (exception 02 or 03) is asked again in halves, so
that the registers it refuses are known and the rest still read; an end
marker whose ``L`` cannot be read ends the chain all the same.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from pymb import maps
from pymb.errors import (
    DeviceException,
    IllegalDataAddress,
    IllegalDataValue,
    ModbusError,
    ModbusTimeout,
    ProtocolError,
)
from pymb.maps.model import Map
from pymb.maps.sunspec.layout import (
    Placed,
    laid_length,
    left_out,
    map_text,
    model_def,
    model_ids,
)

__all__ = ["BASES", "MARKER", "Discovery", "NotSunSpec", "Reader", "discover"]

#: Where the ``SunS`` marker is looked for, in this order (on-wire addresses).
BASES = (40000, 0, 50000)
#: ``SunS`` as two registers.
MARKER = (0x5375, 0x6E53)
_END = 0xFFFF
_MAX_MODELS = 256
#: The largest count tried for a refused count point (each try lays the model out).
_MAX_COUNT = 4096
#: The exceptions of a device that will not read some registers: asked again in parts.
_REFUSALS = (IllegalDataAddress, IllegalDataValue)

#: Reads ``count`` holding registers at ``address``: ``client.read_holding_registers``
#: with the unit id bound.
Reader = Callable[[int, int], Sequence[int]]


class NotSunSpec(ModbusError):
    """The device has no ``SunS`` marker where SunSpec puts it, or its model
    chain is broken."""


@dataclass(frozen=True)
class Discovery:
    """What :func:`discover` found: the marker's address, the models pymb
    knows (in chain order, placed), the ones it skipped (id, address, L),
    one past the end marker, and the most registers the device reads in one
    request (125 unless it refused more)."""

    base: int
    models: tuple[Placed, ...]
    skipped: tuple[tuple[int, int, int], ...] = ()
    end: int = 0
    manufacturer: str = ""
    model: str = ""
    notes: tuple[str, ...] = field(default=())
    max_registers: int = 125

    @property
    def map_id(self) -> str:
        """The map's id: ``sunspec-`` and the model ids, e.g. ``sunspec-1-103-160``."""
        return "sunspec-" + "-".join(str(m.id) for m in self.models)

    def text(self, unit: int = 1) -> str:
        """The device's map, as ``pymb.map/1`` TOML."""
        return map_text(self.models, base=self.base, unit=unit, device_id=self.map_id,
                        manufacturer=self.manufacturer, model=self.model, end=self.end,
                        max_registers=self.max_registers)

    def map(self, unit: int = 1) -> Map:
        """The device's map, loaded."""
        return maps.loads(self.text(unit), source=f"sunspec:{unit}")


def _text(regs: Sequence[int]) -> str:
    raw = b"".join(r.to_bytes(2, "big") for r in regs)
    return raw.split(b"\0")[0].decode("utf-8", "replace").strip()  # as the map reads it


@dataclass
class _Reads:
    """What reading a device's models taught: the registers it refuses, the
    most registers one request read, and whether a request was refused
    whose parts then all read (the device reads fewer at a time)."""

    refused: list[int] = field(default_factory=list)
    widest: int = 0
    too_wide: bool = False


def _read(read: Reader, address: int, count: int, seen: _Reads) -> list[int]:
    """``count`` registers from ``address``, in requests of at most 125; a
    request the device refuses is asked again in halves, down to single
    registers: those it refuses read 0xFFFF and are noted in ``seen``."""
    out: list[int] = []
    while count > 0:
        n = min(count, 125)
        try:
            got = list(read(address, n))
            seen.widest = max(seen.widest, n)
        except _REFUSALS:
            if n == 1:
                seen.refused.append(address)
                got = [_END]
            else:
                half, before = n // 2, len(seen.refused)
                got = _read(read, address, half, seen)
                got += _read(read, address + half, n - half, seen)
                seen.too_wide |= len(seen.refused) == before
        out.extend(got)
        address += n
        count -= n
    return out


def _header(read: Reader, address: int) -> tuple[int, int | None]:
    """A model's ID and L at ``address`` (L None when the device will not
    read it: a device may stop at the end marker's 0xFFFF, or put it at
    register 65535)."""
    if address + 2 <= 0x10000:
        try:
            mid, length = read(address, 2)
            return int(mid), int(length)
        except _REFUSALS:
            pass
    try:
        (mid,) = read(address, 1)
    except _REFUSALS as e:
        raise NotSunSpec(f"the SunSpec model chain breaks at register {address}: the device "
                         f"will not read it (exception {e.code:02d}) and no end marker "
                         "(0xFFFF) came before it") from None
    return int(mid), None


def _counted(placed: Placed, refused: Sequence[int]) -> Placed:
    """``placed`` with each refused register that counts a repeating group
    (``NPt``...) given the count that fills the model's ``L`` exactly (or
    else the first that fills most of it); a register that counts nothing
    stays 0xFFFF."""
    assert placed.registers is not None
    regs = list(placed.registers)
    whole = placed.length + 2

    def laid(i: int, k: int) -> int:
        regs[i] = k
        return laid_length(Placed(placed.id, placed.address, placed.length, placed.prefix,
                                  tuple(regs)))

    for a in refused:
        i = a - placed.address
        if laid(i, 0) == laid(i, 1):  # counts nothing
            regs[i] = _END
            continue
        best, most = 0, -1
        for k in range(min(whole, _MAX_COUNT) + 1):
            n = laid(i, k)
            if n == whole:
                best = k
                break
            if most < n <= whole:
                best, most = k, n
        regs[i] = best
    return Placed(placed.id, placed.address, placed.length, placed.prefix, tuple(regs))


def _ranges(addresses: Sequence[int]) -> str:
    """``40080..40082, 40090``: runs of consecutive addresses."""
    runs: list[list[int]] = []
    for a in addresses:
        if runs and runs[-1][1] + 1 == a:
            runs[-1][1] = a
        else:
            runs.append([a, a])
    return ", ".join(str(a) if a == b else f"{a}..{b}" for a, b in runs)


def _find_base(read: Reader) -> int:
    tried = []
    for base in BASES:
        try:
            regs = tuple(read(base, 2))
        except (DeviceException, ModbusTimeout, ProtocolError) as e:  # no answer here
            tried.append(f"{base}: {type(e).__name__}")
            continue
        if regs == MARKER:
            return base
        tried.append(f"{base}: {regs[0]:04X} {regs[1]:04X}")
    raise NotSunSpec("no SunSpec device: 'SunS' (0x5375 0x6E53) is at none of holding "
                     f"registers 40000, 0, 50000 ({'; '.join(tried)})")


def discover(read: Reader) -> Discovery:
    """Find the marker and walk the model chain through ``read``."""
    base = _find_base(read)
    known = set(model_ids())
    address = base + 2
    placed: list[Placed] = []
    skipped: list[tuple[int, int, int]] = []
    notes: list[str] = []
    names: dict[str, int] = {}
    seen = _Reads()
    manufacturer = model = ""
    for _ in range(_MAX_MODELS):
        if address >= 0x10000:
            raise NotSunSpec(f"the SunSpec model chain from {base} runs past register 65535 "
                             "without its end marker (0xFFFF)")
        mid, length = _header(read, address)
        if mid == _END:
            widest = seen.widest if seen.too_wide and seen.widest else 125
            if widest < 125:
                notes.append(f"the device reads at most {widest} registers a request: the "
                             "map asks no more")
            return Discovery(base, tuple(placed), tuple(skipped), address + 2, manufacturer,
                             model, tuple(notes), widest)
        if length is None:
            raise NotSunSpec(f"the SunSpec model chain from {base} breaks at register "
                             f"{address}: model {mid} there, and its length L "
                             + ("would be past register 65535" if address == 0xFFFF else
                                "the device will not read"))
        if address + 2 + length > 0x10000:
            raise NotSunSpec(f"SunSpec model {mid} at {address} says L = {length}, past "
                             "register 65535")
        if mid not in known:
            skipped.append((mid, address, length))
            notes.append(f"model {mid} at {address} (L = {length}) skipped: pymb does not "
                         "know it")
        else:
            refused: list[int] = []
            seen.refused = refused
            regs = (mid, length, *_read(read, address + 2, length, seen))
            name = str(model_def(mid)["group"]["name"])
            names[name] = names.get(name, 0) + 1
            prefix = name if names[name] == 1 else f"{name}_{names[name]}"
            placed.append(Placed(mid, address, length, prefix, regs))
            if refused:
                placed[-1] = _counted(placed[-1], refused)
                notes.append(f"model {mid} at {address} (L = {length}): the device refuses to "
                             f"read registers {_ranges(refused)}; the points there read no "
                             "value (unsupported)")
            short = left_out(placed[-1])
            if short:
                notes.append(f"model {mid} at {address} (L = {length}) is shorter than SunSpec "
                             f"defines it: {', '.join(short[:5])}"
                             f"{f' and {len(short) - 5} more' if len(short) > 5 else ''} "
                             "left out")
            if mid == 1 and not manufacturer and len(regs) >= 34:
                manufacturer, model = _text(regs[2:18]), _text(regs[18:34])
        address += 2 + length
    raise NotSunSpec(f"the SunSpec model chain from {base} has more than {_MAX_MODELS} models "
                     "without its end marker (0xFFFF)")
