"""Pure-Python Modbus pieces, written as a user of a pure-Python stack would.

The contenders that hand back raw registers (pymodbus, minimalmodbus,
pylibmodbus, the hand-written pyserial client) turn them into engineering
values with :func:`decode_hub` and :func:`decode_telemetry`; the micro
benchmarks race :func:`crc16` and :func:`decode_hub` against pymb's C. The
layouts come from the shipped maps (no register number here).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

from pymb import maps

__all__ = [
    "CRC_TABLE",
    "crc16",
    "decode_hub",
    "decode_telemetry",
    "read_request",
    "response_length",
]

_NAN = math.nan
_HUB = maps.builtin("hub")
CHANNELS = int(_HUB.options["channels"])  #: a full hub's channels
HUB_REGISTERS = CHANNELS * sum(1 for p in _HUB.points.values() if p.block)  #: 700


def _crc_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
        table.append(crc)
    return tuple(table)


#: CRC-16/MODBUS (reflected polynomial 0xA001), one entry per byte value.
CRC_TABLE = _crc_table()


def crc16(data: bytes | bytearray | memoryview) -> int:
    """CRC-16/MODBUS of ``data``, table-driven, in pure Python."""
    crc = 0xFFFF
    table = CRC_TABLE
    for b in data:
        crc = (crc >> 8) ^ table[(crc ^ b) & 0xFF]
    return crc


def read_request(slave: int, function: int, address: int, count: int) -> bytes:
    """An RTU read request (function 0x03/0x04) with its CRC, low byte first."""
    frame = bytes((slave, function, address >> 8, address & 0xFF, count >> 8, count & 0xFF))
    crc = crc16(frame)
    return frame + bytes((crc & 0xFF, crc >> 8))


def response_length(count: int) -> int:
    """Bytes of the normal RTU reply to a read of ``count`` registers."""
    return 5 + 2 * count


# -- the sensor hub ----------------------------------------------------------------

_Decoder = Callable[[Sequence[int]], list[float]]


def _block_decoder(kind: str, scale: float, no_value: frozenset[int]) -> _Decoder:
    """A list comprehension per block kind: what a user writes by hand."""
    if kind == "sm16":
        div = round(1 / scale)  # tenths: divide by 10, as the document puts it

        def sign_magnitude(raw: Sequence[int]) -> list[float]:
            return [_NAN if r in no_value else
                    -(r & 0x7FFF) / div if r & 0x8000 else r / div for r in raw]
        return sign_magnitude
    if kind == "i16":
        def signed(raw: Sequence[int]) -> list[float]:
            return [_NAN if r in no_value else float(r - 0x10000 if r & 0x8000 else r)
                    for r in raw]
        return signed
    if scale == 1:
        def unsigned(raw: Sequence[int]) -> list[float]:
            return [_NAN if r in no_value else float(r) for r in raw]
        return unsigned
    div = round(1 / scale)

    def scaled(raw: Sequence[int]) -> list[float]:
        return [_NAN if r in no_value else r / div for r in raw]
    return scaled


def _hub_decoders(humidity_unit: float) -> tuple[tuple[int, _Decoder], ...]:
    # [NOTES]: 0x8000 is "no humidity" in the 0.1 % unit, 0x00FF in the 1 % unit: the
    # map's humidity block for that unit has its markers and scale.
    hub = _HUB.configure(humidity_unit=humidity_unit)
    return tuple((i * CHANNELS, _block_decoder(block.type, block.scale or 1.0,
                                               frozenset(block.markers)))
                 for i, block in enumerate(hub.points.values()))


_HUB_DECODERS = {0.1: _hub_decoders(0.1), 1.0: _hub_decoders(1.0)}


def decode_hub(registers: Sequence[int], humidity_unit: float = 0.1) -> list[float]:
    """Registers 31..730 (700 ints) to 700 floats, block-major (the layout of
    :attr:`pymb.devices.hub.HubReading.values`), NaN where there is no value."""
    if len(registers) != HUB_REGISTERS:
        raise ValueError(f"the hub sweep is {HUB_REGISTERS} registers, got {len(registers)}")
    n = CHANNELS
    out: list[float] = []
    for start, decode in _HUB_DECODERS[1.0 if humidity_unit == 1 else 0.1]:
        out += decode(registers[start:start + n])
    return out


# -- the CoolPro -------------------------------------------------------------------

_TELEMETRY = [p for p in maps.builtin("coolpro").points.values() if p.group == "telemetry"]
_TELEMETRY_FIRST = _TELEMETRY[0].address
_TELEMETRY_COUNT = _TELEMETRY[-1].end - _TELEMETRY_FIRST


def decode_telemetry(registers: Sequence[int]) -> list[float]:
    """CoolPro input registers 0..7 to [Vin, Iin, Vout, Iout, temperature,
    uptime, status]: milliunits to units, the 32-bit uptime low word first."""
    if len(registers) != _TELEMETRY_COUNT:
        raise ValueError(f"telemetry is {_TELEMETRY_COUNT} registers, got {len(registers)}")
    out: list[float] = []
    for p in _TELEMETRY:
        i = p.address - _TELEMETRY_FIRST
        if p.count == 2:  # u32, low word first
            out.append(float(registers[i] | registers[i + 1] << 16))
        elif p.scale is None:
            out.append(float(registers[i]))
        else:
            out.append(registers[i] / round(1 / p.scale))
    return out
