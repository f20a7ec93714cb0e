"""The wire-time model: how long a Modbus RTU transaction takes on the line.

One home for it: the read planner, the logger, ``pymb demo`` and ``pymb
bench`` all ask here, so "what the wire allows" means one thing everywhere.

A transaction is the request frame, the silence before the reply, and the
reply frame ([MB-SL] Modbus over Serial Line V1.02, 2.5.1.1). The silence is
at least 3.5 characters (the frame end the device must see) and at least
the device's own turnaround; the two overlap, they do not add up: the
CoolPro's fixed ~8 ms gap ([CP] "Frame timing") *is* its silence after the
request, wider than 3.5 characters at every rate it supports. A character
is a start bit, the data bits, the parity bit if any and the stop bits.

This is a floor: no master can finish a transaction sooner, so a measured
rate can never be above it (pymb's simulator, emulating the line, delivers
each reply exactly at this time). The 3.5-character silence a master owes
after a reply before its next request is left out, because it overlaps the
master's own turnaround.

Also here, as facts of the line: registers travel big-endian
(:func:`registers_to_wire`, :func:`registers_from_wire`, the one pair of
byte-order helpers), and a serial bus's defaults when nothing is said
(:data:`DEFAULT_BAUD`, :data:`DEFAULT_PARITY`, :data:`DEFAULT_TIMEOUT`).
"""

from __future__ import annotations

import sys
from array import array
from collections.abc import Iterable

__all__ = [
    "DEFAULT_BAUD",
    "DEFAULT_PARITY",
    "DEFAULT_TIMEOUT",
    "GAP_CHARS",
    "READ_REPLY_OVERHEAD",
    "READ_REQUEST_BYTES",
    "bits_per_char",
    "char_time",
    "read_bits_time",
    "read_time",
    "registers_from_wire",
    "registers_to_wire",
    "transaction_time",
]

DEFAULT_BAUD = 9600  #: bit/s of a serial bus when nothing is said (both devices' default)
DEFAULT_PARITY = "N"  #: 8N1
DEFAULT_TIMEOUT = 1.0  #: seconds to wait for a reply (the hub may take 500 ms, plus the reply)

_SWAP = sys.byteorder == "little"  # registers go on the wire big-endian

GAP_CHARS = 3.5  #: [MB-SL] 2.5.1.1: the silence that ends a frame, in characters
READ_REQUEST_BYTES = 8  #: address, function, start (2), count (2), CRC (2)
READ_REPLY_OVERHEAD = 5  #: address, function, byte count, CRC (2)


def bits_per_char(parity: str = "N", stop_bits: int = 1, data_bits: int = 8) -> int:
    """Bits one character takes: start + data + parity (E/O) + stop (10 for 8N1)."""
    return 1 + data_bits + (0 if str(parity).upper() in ("N", "NONE") else 1) + stop_bits


def char_time(baudrate: int, bits: int = 10) -> float:
    """Seconds one character takes on the line."""
    return bits / baudrate


def transaction_time(request_bytes: int, reply_bytes: int, baudrate: int, *,
                     turnaround: float = 0.0, bits: int = 10, gap: float = 0.0) -> float:
    """Least seconds from a request's first bit to its reply's last bit, plus
    ``gap``: the silence a device asks for before each request to it (a map's
    ``inter_request_gap``)."""
    c = char_time(baudrate, bits)
    return gap + (request_bytes + reply_bytes) * c + max(GAP_CHARS * c, turnaround)


def read_time(count: int, baudrate: int, *, turnaround: float = 0.0, bits: int = 10,
              gap: float = 0.0) -> float:
    """Least seconds of one read of ``count`` registers (FC 0x03 / 0x04)."""
    return transaction_time(READ_REQUEST_BYTES, READ_REPLY_OVERHEAD + 2 * count, baudrate,
                            turnaround=turnaround, bits=bits, gap=gap)


def read_bits_time(count: int, baudrate: int, *, turnaround: float = 0.0, bits: int = 10,
                   gap: float = 0.0) -> float:
    """Least seconds of one read of ``count`` coils or discrete inputs (FC 0x01 /
    0x02): the reply packs eight to a byte."""
    return transaction_time(READ_REQUEST_BYTES, READ_REPLY_OVERHEAD + (count + 7) // 8,
                            baudrate, turnaround=turnaround, bits=bits, gap=gap)


def registers_to_wire(registers: Iterable[int], *, in_place: bool = False) -> bytes:
    """16-bit registers (an ``array('H')`` or a sequence of ints) as they
    travel: big-endian words. ``in_place``: ``registers`` is a scratch array
    that may be byte-swapped where it is (no copy)."""
    out = registers if in_place and isinstance(registers, array) else array("H", registers)
    if _SWAP:
        out.byteswap()
    return out.tobytes()


def registers_from_wire(data: bytes) -> array[int]:
    """Big-endian 16-bit words as they travel, as an ``array('H')``."""
    out = array("H", data)
    if _SWAP:
        out.byteswap()
    return out
