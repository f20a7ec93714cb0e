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
