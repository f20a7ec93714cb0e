"""The decoders and the hub sweep: the C core's pymb_hub_decode,
pymb_hub_plan_all, pymb_hub_request and the CoolPro decoders, over
preallocated buffers.
"""

from __future__ import annotations

import struct
import threading
from typing import Any

from pymb._pymb_cffi import ffi, lib
from pymb.errors import InvalidArgument

__all__ = [
    "HUB_ALL_BLOCKS",
    "HUB_BITMAP_BYTES",
    "HUB_BLOCKS",
    "HUB_CHANNELS",
    "HUB_REGISTERS",
    "HubSweep",
    "coolpro_identity",
    "coolpro_telemetry",
    "hub_decode",
    "hub_plan_all",
]

_from_buffer = ffi.from_buffer
_NULL = ffi.NULL

HUB_REGISTERS = int(lib.PYMB_HUB_REGISTERS)
HUB_BLOCKS = int(lib.PYMB_HUB_BLOCKS)
HUB_ALL_BLOCKS = int(lib.PYMB_HUB_ALL_BLOCKS)  #: the block mask with every block set
HUB_CHANNELS = int(lib.PYMB_HUB_CHANNELS)
HUB_BITMAP_BYTES = int(lib.PYMB_HUB_BITMAP_BYTES)


def hub_decode(regs: Any, channels: int, tenths: bytes | None, wanted: bytes | None,
               read_mask: int, unsupported: int, values: Any, states: Any) -> None:
    """Decode 700 raw hub registers into ``values`` (float64) and ``states``
    (uint8), 7 x ``channels`` each, block-major (see pymb_hub_decode)."""
    rq = ffi.new("pymb_hub_request *")
    # pymb_hub_decode reads PYMB_HUB_REGISTERS registers: a shorter buffer is
    # refused here, before C could read past it.
    keep = (_from_buffer("uint16_t[]", regs), _from_buffer("double[]", values, True),
            _from_buffer("uint8_t[]", states, True),
            _NULL if tenths is None else ffi.from_buffer("uint8_t[]", tenths),
            _NULL if wanted is None else ffi.from_buffer("uint8_t[]", wanted))
    rq.regs, rq.values, rq.states, rq.humidity_tenths, rq.wanted = keep
    rq.channels = channels
    rq.read_mask = read_mask
    rq.unsupported = unsupported
    rq.out_len = len(values)
    rc = -1 if len(regs) != HUB_REGISTERS else lib.pymb_hub_decode(rq)
    if rc < 0:
        raise InvalidArgument(
            f"cannot decode {len(regs)} registers for {channels} channels: the hub block is "
            f"{HUB_REGISTERS} registers (31..730) and 1..{HUB_CHANNELS} channels"
        )


def hub_plan_all(skip_mask: int, channels: int) -> list[tuple[int, int]]:
    """The C core's plan for a full sweep: (address, count) requests."""
    spans = ffi.new("pymb_span[]", 16)
    n = lib.pymb_hub_plan_all(skip_mask, channels, spans, 16)
    if n < 0:
        raise InvalidArgument(f"cannot plan a sweep of {channels} channels")
    return [(spans[i].address, spans[i].count) for i in range(n)]


class HubSweep:
    """A prepared ``pymb_hub_request``: slave, channels, humidity units, the
    plan and the firmware knowledge, kept across sweeps of one device."""

    def __init__(self, slave: int, channels: int, tenths: bytes, busy_retries: int,
                 busy_backoff: float) -> None:
        self.request = rq = ffi.new("pymb_hub_request *")
        self._tenths = ffi.new("uint8_t[]", tenths)
        self._spans = ffi.new("pymb_span[]", HUB_REGISTERS)
        self._wanted: Any = ffi.NULL
        rq.slave = slave
        rq.channels = channels
        rq.humidity_tenths = self._tenths
        rq.options.busy_retries = busy_retries
        rq.options.busy_backoff_us = round(busy_backoff * 1e6)
        rq.spans = self._spans

    def set_plan(self, spans: list[tuple[int, int]], wanted: bytes | None) -> None:
        """The requests to make and the registers wanted (None: all asked)."""
        for i, (address, count) in enumerate(spans):
            self._spans[i].address = address
            self._spans[i].count = count
        self.request.nspans = len(spans)
        self._wanted = ffi.NULL if wanted is None else ffi.new("uint8_t[]", wanted)
        self.request.wanted = self._wanted

    @property
    def wanted(self) -> bytes | None:
        """The wanted-register bitmap of the current plan."""
        return None if self._wanted == ffi.NULL else bytes(ffi.buffer(self._wanted))

    @property
    def unsupported(self) -> int:
        """Bit mask of the blocks the firmware lacks (as far as known)."""
        return int(self.request.unsupported)

    @unsupported.setter
    def unsupported(self, mask: int) -> None:
        self.request.unsupported = mask

    def bind(self, regs: Any, values: Any, states: Any) -> tuple[Any, ...]:
        """Point the request at this reading's buffers; keep the result alive
        until the sweep returns."""
        rq = self.request
        keep = (
            ffi.from_buffer("uint16_t[]", regs, require_writable=True),
            ffi.from_buffer("double[]", values, require_writable=True),
            ffi.from_buffer("uint8_t[]", states, require_writable=True),
        )
        rq.regs, rq.values, rq.states = keep
        rq.out_len = len(values)
        return keep

    def unbind(self) -> None:
        """Forget the reading's buffers (they may be freed after the sweep)."""
        rq = self.request
        rq.regs = rq.values = rq.states = _NULL


_telemetry_local = threading.local()


def _unpacker(ctype: str) -> struct.Struct:
    """A struct.Struct reading a C struct of doubles and unsigned ints field
    by field at the offsets the compiler chose: all its fields in one call
    (attribute reads on cdata cost a call each)."""
    codes = {"double": "d", "uint32_t": "I", "uint16_t": "H", "uint8_t": "B"}
    fmt, pos = "=", 0
    for _, f in ffi.typeof(ctype).fields:
        fmt += "x" * (f.offset - pos) + codes[f.type.cname]
        pos = f.offset + ffi.sizeof(f.type)
    return struct.Struct(fmt)


_TELEMETRY = _unpacker("pymb_coolpro_telemetry")


def coolpro_telemetry(regs: Any) -> tuple[float, float, float, float, float, int, int]:
    """Decode input registers 0..7: (Vin, Iin, Vout, Iout, temperature, uptime, status)."""
    out = getattr(_telemetry_local, "out", None)
    if out is None:  # one output struct per thread, not one allocation per read
        t = ffi.new("pymb_coolpro_telemetry *")
        out = _telemetry_local.out = (t, ffi.buffer(t))
    if lib.pymb_coolpro_decode_telemetry(_from_buffer("uint16_t[]", regs), len(regs), out[0]):
        raise InvalidArgument(f"telemetry is 8 registers, got {len(regs)}")
    values: tuple[float, float, float, float, float, int, int] = _TELEMETRY.unpack_from(out[1])
    return values


def coolpro_identity(regs: Any) -> tuple[int, int, int, int, int, int]:
    """Decode input registers 100..107: (serial, hw rev, major, minor, patch, manufactured)."""
    d = ffi.new("pymb_coolpro_identity *")
    if lib.pymb_coolpro_decode_identity(ffi.from_buffer("uint16_t[]", regs), len(regs), d):
        raise InvalidArgument(f"identity is 8 registers, got {len(regs)}")
    return (int(d.serial_number), int(d.hardware_revision), int(d.firmware_major),
            int(d.firmware_minor), int(d.firmware_patch), int(d.manufactured))
