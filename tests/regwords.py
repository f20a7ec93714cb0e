"""Register images of values as vendor documents lay them out, for the
shipped maps' tests."""

from __future__ import annotations

import struct


def f32(v: float) -> list[int]:
    """An IEEE 754 single as two registers, high word first."""
    hi, lo = struct.unpack(">HH", struct.pack(">f", v))
    return [hi, lo]


def lsw_first(v: int, words: int = 2) -> list[int]:
    """A two's complement integer as registers, least significant word first."""
    u = v & ((1 << (16 * words)) - 1)
    return [(u >> (16 * i)) & 0xFFFF for i in range(words)]
