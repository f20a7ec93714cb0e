"""Slow, obvious pure-Python decoders and the RTU CRC, straight from the
documents: the reference the C core is tested against (and the CRC the
scripted peers frame with). Kept in tests/ only."""

from __future__ import annotations

import math

OFFLINE, NO_SENSOR, VALUE = "offline", "no sensor", "value"
NAN = math.nan


def sign_magnitude_tenths(raw: int) -> tuple[str, float]:
    """[HUB] 3: bit 15 sign (1 = negative), bits 14..0 in 0.1 degC; 0xFFFF offline."""
    if raw == 0xFFFF:
        return OFFLINE, NAN
    magnitude = (raw & 0x7FFF) / 10
    return VALUE, -magnitude if raw & 0x8000 else magnitude


def humidity(raw: int, unit: float) -> tuple[str, float]:
    """[HUB] 3 / [NOTES]: 0xFFFF offline; 0x00FF no humidity in 1 % unit,
    0x8000 no humidity in 0.1 % unit."""
    if raw == 0xFFFF:
        return OFFLINE, NAN
    if unit == 1:
        return (NO_SENSOR, NAN) if raw == 0x00FF else (VALUE, float(raw))
    return (NO_SENSOR, NAN) if raw == 0x8000 else (VALUE, raw / 10)


def unsigned(raw: int) -> tuple[str, float]:
    """Pressure (kPa) and voltage (mV): unsigned; 0xFFFF offline."""
    return (OFFLINE, NAN) if raw == 0xFFFF else (VALUE, float(raw))


def signed(raw: int) -> tuple[str, float]:
    """RSSI: two's complement 16-bit dBm; 0xFFFF offline."""
    if raw == 0xFFFF:
        return OFFLINE, NAN
    return VALUE, float(raw - 0x10000 if raw & 0x8000 else raw)


def hub_value(block: int, raw: int, unit: float) -> tuple[str, float]:
    """Decode one register of block 0..6 (31.., 131.., ... 631..)."""
    if block in (0, 2, 6):
        return sign_magnitude_tenths(raw)
    if block == 1:
        return humidity(raw, unit)
    if block == 5:
        return signed(raw)
    return unsigned(raw)


def milli(raw: int) -> float:
    """[CP] ch. 04: milliunits."""
    return raw / 1000


def u32_low_word_first(low: int, high: int) -> int:
    """[CP] ch. 04: (high << 16) | low."""
    return (high << 16) | low


def coolpro_telemetry(regs: list[int]) -> tuple[float, float, float, float, float, int, int]:
    """[CP] ch. 03/04, input registers 0..7: (Vin, Iin, Vout, Iout, temperature
    in milliunits, uptime low word first, status)."""
    return (milli(regs[0]), milli(regs[1]), milli(regs[2]), milli(regs[3]), milli(regs[4]),
            u32_low_word_first(regs[5], regs[6]), regs[7])


def coolpro_identity(regs: list[int]) -> tuple[int, int, int, int, int, int]:
    """[CP] ch. 03/04, input registers 100..107: (serial, hardware revision,
    firmware major, minor, patch, manufactured), 32-bit values low word first."""
    return (u32_low_word_first(regs[0], regs[1]), regs[2], regs[3], regs[4], regs[5],
            u32_low_word_first(regs[6], regs[7]))


def hub_sweep_spans(skip_mask: int, channels: int) -> list[tuple[int, int]]:
    """[HUB] 3 / [NOTES]: the fewest reads (at most 125 registers each) of
    channels 1..channels of every block not in skip_mask (bit b: block b);
    whole blocks are contiguous on the wire, so they merge only when every
    one of the 100 channels is read."""
    runs: list[tuple[int, int]] = []
    for b in range(7):
        if skip_mask >> b & 1:
            continue
        start = 31 + 100 * b
        if channels == 100 and runs and runs[-1][1] == start:
            runs[-1] = (runs[-1][0], start + channels)
        else:
            runs.append((start, start + channels))
    spans = []
    for start, end in runs:
        for a in range(start, end, 125):
            spans.append((a, min(125, end - a)))
    return spans


def crc16(data: bytes) -> int:
    """CRC-16/MODBUS, bit by bit ([MB-SL] 6.2.2): the polynomial 0xA001
    (reflected 0x8005), initial value 0xFFFF."""
    c = 0xFFFF
    for b in data:
        c ^= b
        for _ in range(8):
            c = (c >> 1) ^ 0xA001 if c & 1 else c >> 1
    return c


def crc(data: bytes) -> bytes:
    """The CRC as an RTU frame carries it: low byte first."""
    return crc16(data).to_bytes(2, "little")
