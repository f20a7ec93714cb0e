"""The client's argument checks and per-request limits: every argument is
checked here before anything is sent, and the limits are the compiler's
(libmodbus's modbus.h)."""

from __future__ import annotations

import errno
import operator
from array import array
from collections.abc import Iterable, Mapping, Set
from typing import TYPE_CHECKING, SupportsIndex, cast

from pymb import _native
from pymb.errors import InvalidArgument
from pymb.wire import registers_to_wire

if TYPE_CHECKING:
    from typing_extensions import Buffer

__all__ = ["FC", "MAX_READ_BITS", "MAX_READ_REGISTERS", "MAX_WRITE_BITS",
           "MAX_WRITE_REGISTERS", "MAX_WR_READ_REGISTERS", "MAX_WR_WRITE_REGISTERS"]

# Function codes and per-request limits: the compiler's (libmodbus's modbus.h).
MAX_READ_REGISTERS = _native.MAX_READ_REGISTERS
MAX_WRITE_REGISTERS = _native.MAX_WRITE_REGISTERS
MAX_WR_WRITE_REGISTERS = _native.MAX_WR_WRITE_REGISTERS
MAX_WR_READ_REGISTERS = _native.MAX_WR_READ_REGISTERS
MAX_READ_BITS = _native.MAX_READ_BITS
MAX_WRITE_BITS = _native.MAX_WRITE_BITS
FC = _native.FunctionCode

_PARITIES = {"N": "N", "E": "E", "O": "O", "NONE": "N", "EVEN": "E", "ODD": "O"}
# OS errors after which the link is gone until it is opened again.
#: what a connection the peer closed (or reset) fails with
_CLOSED_BY_PEER = frozenset((errno.EPIPE, errno.ECONNRESET))
_LINK_LOST = frozenset((errno.EIO, errno.ENXIO, errno.ENODEV, errno.EBADF, errno.EPIPE,
                        errno.ECONNRESET, errno.ECONNREFUSED, errno.ENOENT))

_SERIAL_MODES = _native.SERIAL_MODES
_RTS_MODES = _native.RTS_MODES


def _int(name: str, value: object, low: int, high: int) -> int:
    # Any integer (numpy's too, through __index__), but not a bool or a float.
    if isinstance(value, bool) or not hasattr(type(value), "__index__"):
        raise InvalidArgument(f"{name} must be an integer from {low} to {high}, got {value!r}")
    number = operator.index(cast(SupportsIndex, value))
    if not low <= number <= high:
        raise InvalidArgument(f"{name} must be from {low} to {high}, got {number}")
    return number


def _seconds(name: str, value: object, *, allow_zero: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InvalidArgument(f"{name} must be a number of seconds, got {value!r}")
    v = float(value)
    if not (v >= 0.0 if allow_zero else v > 0.0) or v > 3600.0:
        raise InvalidArgument(
            f"{name} must be {'0..3600' if allow_zero else 'more than 0 and at most 3600'} "
            f"seconds, got {value!r}"
        )
    return v


def _coil(value: object) -> int:
    """A coil value: a bool, or the integers 0 and 1, and nothing else."""
    if isinstance(value, bool):
        return int(value)
    if (getattr(getattr(value, "dtype", None), "kind", None) == "b"
            and getattr(value, "ndim", None) == 0):
        return int(bool(value))  # a numpy bool (an element of a bool array)
    if isinstance(value, (str, bytes, bytearray, memoryview, float)) or not hasattr(
            type(value), "__index__"):
        raise TypeError(
            f"a coil value is a bool or 0 or 1, got {type(value).__name__} {value!r}")
    v = operator.index(cast(SupportsIndex, value))
    if v not in (0, 1):
        raise InvalidArgument(f"a coil value is a bool or 0 or 1, got {value!r}")
    return v


def _register_values(values: object) -> bytes:
    """Register values (ints 0..65535, not bools, not bytes) as big-endian bytes."""
    if isinstance(values, array) and values.typecode == "H":
        a = values
    else:
        if isinstance(values, (Set, Mapping)):
            raise TypeError(f"register values are a sequence, not a {type(values).__name__} "
                            "(which has no order)")
        if isinstance(values, (str, bytes, bytearray, memoryview)):
            raise TypeError(
                "register values are a sequence of integers 0..65535 (an array('H') or a "
                f"list), not {type(values).__name__}: bytes would depend on byte order")
        try:
            items = list(cast(Iterable[object], values))
        except TypeError:
            raise TypeError(
                f"register values must be a sequence of integers, got {type(values).__name__}"
            ) from None
        for v in items:
            if isinstance(v, bool) or not hasattr(type(v), "__index__") or isinstance(
                    v, float):
                raise TypeError(
                    f"a register value is an integer 0..65535, got {type(v).__name__} {v!r}")
            if not 0 <= operator.index(cast(SupportsIndex, v)) <= 0xFFFF:
                raise InvalidArgument(f"a register value is 0..65535, got {v!r}")
        a = array("H", [operator.index(cast(SupportsIndex, v)) for v in items])
    if len(a) == 0:
        raise InvalidArgument("no values to write")
    return registers_to_wire(a)


def _coil_payload(values: object) -> tuple[int, bytes]:
    """Coil values (bools or 0/1) -> (how many, packed LSB first, FC 0x0F)."""
    if isinstance(values, (str, bytes, bytearray, memoryview, Set, Mapping)):
        raise TypeError(f"coil values are a sequence of bools or 0/1, not "
                        f"{type(values).__name__}")
    try:
        bits = [_coil(v) for v in cast(Iterable[object], values)]
    except TypeError as e:
        if "coil value" in str(e):
            raise
        raise TypeError(f"coil values must be a sequence, got {type(values).__name__}"
                        ) from None
    packed = bytearray((len(bits) + 7) // 8)
    for i, b in enumerate(bits):
        if b:
            packed[i // 8] |= 1 << (i % 8)
    return len(bits), bytes(packed)


def _pdu_data(data: object) -> bytes:
    """A raw request's data as bytes: bytes-like of 1-byte items or integers 0..255,
    at most a PDU's worth."""
    if isinstance(data, (str, int)):  # bytes(3) would be three zero bytes
        raise TypeError("data must be bytes (or a sequence of integers 0..255), not "
                        f"{type(data).__name__}")
    try:
        view = memoryview(cast("Buffer", data))
    except TypeError:
        view = None
    if view is not None and view.itemsize != 1:
        raise TypeError(
            f"data must be bytes, not a buffer of {view.itemsize}-byte items (its bytes "
            "would depend on the host's byte order)")
    try:
        payload = view.tobytes() if view is not None else bytes(cast(Iterable[SupportsIndex], data))
    except ValueError:
        raise InvalidArgument("data bytes must be integers 0..255") from None
    except TypeError:
        raise TypeError(
            f"data must be bytes or a sequence of integers 0..255, got "
            f"{type(data).__name__}") from None
    if len(payload) > _native.MAX_PDU_DATA:
        raise InvalidArgument(f"data is {len(payload)} bytes; a PDU holds at most "
                              f"{_native.MAX_PDU_DATA}")
    return payload


def _range(address: int, count: int, limit: int | None) -> tuple[int, int]:
    """``address`` and ``count`` checked: count 1..limit (any when None), within 0..65535."""
    address = _int("address", address, 0, 0xFFFF)
    count = _int("count", count, 1, 0x10000 if limit is None else limit)
    if address + count > 0x10000:
        raise InvalidArgument(
            f"address {address} + count {count} runs past the last address 65535"
        )
    return address, count


def _u16_dest(dest: object) -> memoryview:
    """A read's destination as a memoryview: a writable, contiguous buffer of
    unsigned 16-bit integers (``array('H')``, numpy uint16)."""
    try:
        view = memoryview(cast("Buffer", dest))
    except TypeError:
        raise TypeError(
            f"dest must be a writable uint16 buffer (array('H')), got {type(dest).__name__}"
        ) from None
    # Not a signed 'h' buffer either: register 40000 would read as -25536.
    problem = ("is read-only" if view.readonly else
               "is not C-contiguous" if not view.c_contiguous else
               f"has items of format {view.format!r}"
               if view.itemsize != 2 or view.format.lstrip("@=") != "H" else None)
    if problem:
        raise InvalidArgument(
            "dest must be a writable, contiguous buffer of unsigned 16-bit integers "
            f"(array('H'), numpy uint16); this one {problem}")
    return view
