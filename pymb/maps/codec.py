"""The reference codec in pure Python: one point's registers to its value and
back, exactly as the contract's section 3 says. The C decoder
(``pymb_map_decode``) is tested against it; it is also what
:meth:`Map.decode` and :meth:`Map.encode` use.

Decoding never raises on data: a marker, NaN or text invalid in its encoding
gives None and a named state.
"""

from __future__ import annotations

import functools
import math
import struct
from collections.abc import Sequence

from pymb.errors import InvalidArgument
from pymb.maps.point import MapError, Point, Points, PointState, Value, did_you_mean
from pymb.maps.types import SF_RANGE, STATES, TYPES, permutation

__all__ = ["decimal_power", "decode", "decode_one", "encode", "scaled", "state_names"]

_FLOAT = {2: "e", 4: "f", 8: "d"}


@functools.lru_cache(maxsize=256)
def _perm(order: str) -> tuple[int, ...]:
    return permutation(order)


@functools.lru_cache(maxsize=256)
def _inverse(order: str) -> tuple[int, ...]:
    perm = permutation(order)
    inv = [0] * len(perm)
    for k, pos in enumerate(perm):
        inv[pos] = k
    return tuple(inv)


@functools.lru_cache(maxsize=256)
def decimal_power(scale: float | None) -> int:
    """k when ``scale`` is the double nearest 10**-k (1 <= k <= 22), else 0:
    such a scale divides by 10**k instead of multiplying."""
    if scale is None or not 0 < scale < 1:
        return 0
    for k in range(1, 23):
        if scale == float(f"1e-{k}"):
            return k
    return 0


def scaled(raw: float, p: Point, negative: bool = False, sf: int = 0) -> float:
    """``raw * scale + offset`` in binary64, dividing by 10**k for a decimal
    scale (``raw * 10**sf`` for a ``scale_from`` point, dividing by
    10**-sf for a negative one); ``negative`` negates before the offset
    (sign-magnitude)."""
    k = decimal_power(p.scale)
    v = float(raw)
    if p.scale_from is not None:
        v = v / 10.0 ** -sf if sf < 0 else v * 10.0 ** sf
    elif k:
        v = v / 10.0 ** k
    elif p.scale is not None:
        v = v * p.scale
    if negative:
        v = -v
    if p.offset is not None:
        v = v + p.offset
    return v


def _pattern(p: Point, regs: Sequence[int]) -> int:
    """The value's bits as an unsigned integer, the point's order applied."""
    if p.count == 1 and p.order == "AB":
        return regs[0] & 0xFFFF
    wire = struct.pack(f">{p.count}H", *(r & 0xFFFF for r in regs[:p.count]))
    return int.from_bytes(bytes(wire[i] for i in _perm(p.order)), "big")


def _signed(u: int, bits: int) -> int:
    return u - (1 << bits) if u >> (bits - 1) & 1 else u


def _text(p: Point, regs: Sequence[int]) -> tuple[Value, str]:
    swap = p.order == "BA"
    out = bytearray()
    for r in regs[:p.count]:
        hi, lo = (r >> 8) & 0xFF, r & 0xFF
        if swap:
            hi, lo = lo, hi
        if p.string_bytes == "both":
            out += bytes((hi, lo))
        else:
            out.append(hi if p.string_bytes == "high" else lo)
    end = out.find(0)
    data = bytes(out if end < 0 else out[:end])
    if not data and 0 in p.markers:  # a string's marker 0: the empty text
        return None, p.markers[0]
    try:
        return data.decode(p.encoding), "value"
    except UnicodeDecodeError:
        return None, "invalid_text"


def scale_factor_ok(sf: int | None) -> bool:
    """True when ``sf`` is a scale factor a ``scale_from`` point can use."""
    return sf is not None and SF_RANGE[0] <= sf <= SF_RANGE[1]


def decode_one(p: Point, regs: Sequence[int], sf: int | None = None) -> tuple[Value, str]:
    """(value, state name) of one channel from its ``p.count`` registers;
    ``sf``: the value of its ``scale_from`` point (None: not read)."""
    if len(regs) < p.count:
        raise MapError(f"point {p.name!r} needs {p.count} registers, got {len(regs)}",
                       point=p.name)
    t = p.type
    family = TYPES[t].family
    if family == "bool":
        return bool(regs[0]), "value"
    if family == "raw":
        return [r & 0xFFFF for r in regs[:p.count]], "value"
    if family == "string":
        return _text(p, regs)
    u = _pattern(p, regs)
    if family == "bit":
        return bool(u >> (p.bit or 0) & 1), "value"
    if family == "bits":
        u = u >> (p.shift or 0) & ((1 << (p.width or 1)) - 1)
    elif family == "half":
        u = u >> 8 if t.endswith("_hi") else u & 0xFF
    if p.mask is not None:
        u &= p.mask
    if u in p.markers:
        return None, p.markers[u]
    for pattern, care, state in p.marker_masks:
        if u & care == pattern:
            return None, state
    if p.scale_from is not None:
        if not scale_factor_ok(sf):
            return None, "no_scale"
        return _scaled_value(p, u, family, sf or 0)
    plain = p.scale is None and p.offset is None
    if family == "float":
        f = struct.unpack(">" + _FLOAT[2 * p.count], u.to_bytes(2 * p.count, "big"))[0]
        if math.isnan(f):
            return None, "nan"
        return (f if plain else scaled(f, p)), "value"
    if family == "sm":
        mag, negative = u & 0x7FFF, bool(u & 0x8000)
        if plain:
            return (-mag if negative else mag), "value"
        return scaled(mag, p, negative), "value"
    if TYPES[t].signed:
        u = _signed(u, 8 if family == "half" else 16 * p.count)
    return (u if plain else scaled(u, p)), "value"


def _scaled_value(p: Point, u: int, family: str, sf: int) -> tuple[Value, str]:
    """(value, state) of a ``scale_from`` point from its raw pattern ``u``."""
    if family == "float":
        f = struct.unpack(">" + _FLOAT[2 * p.count], u.to_bytes(2 * p.count, "big"))[0]
        return (None, "nan") if math.isnan(f) else (scaled(f, p, sf=sf), "value")
    if family == "sm":
        return scaled(u & 0x7FFF, p, bool(u & 0x8000), sf), "value"
    if TYPES[p.type].signed:
        u = _signed(u, 8 if family == "half" else 16 * p.count)
    return scaled(u, p, sf=sf), "value"


def decode(p: Point, regs: Sequence[int], sf: int | None = None) -> tuple[Value, PointState]:
    """(value, state) of a point, or two lists for a block: ``regs`` starts
    at the first channel's first register; ``sf``: the value of its
    ``scale_from`` point, if it has one."""
    if not p.block:
        return decode_one(p, regs, sf)
    if len(regs) < p.span:
        raise MapError(f"block {p.name!r} spans {p.span} registers, got {len(regs)}",
                       point=p.name)
    pairs = [decode_one(p, regs[c * p.stride:c * p.stride + p.count], sf)
             for c in range(p.channels)]
    return [v for v, _ in pairs], [s for _, s in pairs]


def _refuse(p: Point, why: str) -> InvalidArgument:
    return InvalidArgument(f"point {p.name!r}: {why}")


def _number(p: Point, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise _refuse(p, f"a number is needed, got {value!r}")
    return value


def _to_regs(p: Point, u: int) -> list[int]:
    n = 2 * p.count
    value = u.to_bytes(n, "big")
    wire = bytes(value[k] for k in _inverse(p.order)) if p.order else value
    return list(struct.unpack(f">{p.count}H", wire))


def _unscale(p: Point, v: float, sf: int | None) -> float:
    if p.offset is not None:
        v = v - p.offset
    if p.scale_from is not None:
        if not scale_factor_ok(sf):
            raise _refuse(p, f"its scale factor ({p.scale_from}) is needed to write it, and "
                          f"must be {SF_RANGE[0]}..{SF_RANGE[1]}, got {sf!r}")
        s = sf or 0
        return v * 10.0 ** -s if s < 0 else v / 10.0 ** s
    k = decimal_power(p.scale)
    if k:
        return v * 10.0 ** k
    return v / p.scale if p.scale is not None else v


def encode(p: Point, value: object, *, current: Sequence[int] | None = None,
           check_access: bool = True, sf: int | None = None) -> list[int]:
    """The registers (bits for a coil) that write ``value`` to one channel of
    ``p``; :class:`InvalidArgument` for anything the point refuses. ``sf``:
    the value of its ``scale_from`` point, if it has one."""
    if check_access and not p.writable:
        raise _refuse(p, "read-only (access = \"r\")")
    t = p.type
    family = TYPES[t].family
    if p.values:
        if isinstance(value, str):
            names = {n: k for k, n in p.values.items()}
            if value not in names:
                raise _refuse(p, f"{value!r} is not one of its values"
                              f"{did_you_mean(value, list(names))}")
            value = names[value]
        elif value not in p.values or isinstance(value, float):
            raise _refuse(p, f"{value!r} is not one of its values "
                          f"({', '.join(f'{k} = {n}' for k, n in p.values.items())})")
    if family == "bool":
        if value not in (0, 1) or isinstance(value, float):
            raise _refuse(p, f"true or false is needed, got {value!r}")
        return [int(bool(value))]
    if family == "raw":
        if (not isinstance(value, (list, tuple)) or len(value) != p.count
                or not all(isinstance(r, int) and 0 <= r <= 0xFFFF for r in value)):
            raise _refuse(p, f"a list of {p.count} registers 0..65535 is needed")
        return list(value)
    if family == "string":
        return _encode_text(p, value)
    if family == "bit":
        if value not in (0, 1) or isinstance(value, float):
            raise _refuse(p, f"true or false is needed, got {value!r}")
        value = int(bool(value))
    v = _number(p, value)
    if p.valid is not None and not p.valid[0] <= v <= p.valid[1]:
        raise _refuse(p, f"{value!r} is outside its valid range {p.valid[0]:g}..{p.valid[1]:g}")
    if family == "float":
        f = _unscale(p, float(v), sf)
        try:
            u = int.from_bytes(struct.pack(">" + _FLOAT[2 * p.count], f), "big")
        except (OverflowError, struct.error):
            raise _refuse(p, f"{value!r} does not fit a {t}") from None
        return _to_regs(p, u)
    raw = _unscale(p, v, sf)
    if family == "bit":
        raw_int = 1 if v else 0
    else:
        if not math.isfinite(raw):
            raise _refuse(p, f"{value!r} is not a finite number")
        raw_int = round(raw)
        if p.scale is None and p.offset is None and p.scale_from is None and raw_int != raw:
            raise _refuse(p, f"a whole number is needed, got {value!r}")
        sent = scaled(raw_int, p, sf=sf or 0)
        if raw_int != raw and p.valid is not None and not p.valid[0] <= sent <= p.valid[1]:
            # the nearest step of the scale lies outside: that is what would be sent
            raise _refuse(p, f"{value!r} would be written as {sent:g} (the nearest step of its "
                          f"scale), outside its valid range {p.valid[0]:g}..{p.valid[1]:g}")
    if family == "bits":
        lo, hi = 0, (1 << (p.width or 1)) - 1
    else:
        lo, hi = TYPES[t].raw_range()
    if not lo <= raw_int <= hi:
        raise _refuse(p, f"{value!r} is outside the range of a {t}"
                      + (f" (raw {raw_int}, {lo}..{hi})" if raw_int != v else f" ({lo}..{hi})"))
    if family == "sm":
        u = (0x8000 | -raw_int) if raw_int < 0 else raw_int
        return _to_regs(p, u)
    if family == "int" and p.mask is not None:
        if raw_int & ~p.mask:
            raise _refuse(p, f"{value!r} has bits outside its mask 0x{p.mask:X}")
        if current is None or len(current) < p.count:
            raise _refuse(p, "a masked value shares its register: pass the register's current "
                          "contents (current=...) to write it")
        return _to_regs(p, (_pattern(p, current) & ~p.mask) | raw_int)
    if family == "int":
        return _to_regs(p, raw_int & ((1 << (16 * p.count)) - 1))
    if current is None or len(current) < p.count:
        raise _refuse(p, f"a {t} view shares its register: pass the register's current "
                      "contents (current=...) to write it")
    u = _pattern(p, current)
    if family == "half":
        byte = raw_int & 0xFF
        u = (u & 0x00FF) | byte << 8 if t.endswith("_hi") else (u & 0xFF00) | byte
    else:
        shift = p.bit if family == "bit" else p.shift
        width = 1 if family == "bit" else p.width
        mask = ((1 << (width or 1)) - 1) << (shift or 0)
        u = (u & ~mask) | (raw_int << (shift or 0) & mask)
    return _to_regs(p, u)


def _encode_text(p: Point, value: object) -> list[int]:
    if not isinstance(value, str):
        raise _refuse(p, f"text is needed, got {value!r}")
    if "\0" in value:  # a read ends the text there: it could never read back as written
        raise _refuse(p, f"{value!r} has a NUL character, which ends a text")
    try:
        data = value.encode(p.encoding)
    except UnicodeEncodeError:
        raise _refuse(p, f"{value!r} cannot be written in {p.encoding}") from None
    per = 2 if p.string_bytes == "both" else 1
    if len(data) > per * p.count:
        raise _refuse(p, f"{value!r} is longer than {per * p.count} bytes")
    data = data.ljust(per * p.count, b"\0")
    regs = []
    for i in range(p.count):
        if per == 2:
            hi, lo = data[2 * i], data[2 * i + 1]
        else:
            hi, lo = (data[i], 0) if p.string_bytes == "high" else (0, data[i])
        if p.order == "BA":
            hi, lo = lo, hi
        regs.append(hi << 8 | lo)
    return regs


@functools.lru_cache(maxsize=64)
def state_names(m: Points) -> tuple[str, ...]:
    """The fixed states, padded to code 16, then the map's own marker names."""
    names = list(STATES) + [""] * (16 - len(STATES))
    for p in m.points.values():
        for s in (*p.markers.values(), *(m[2] for m in p.marker_masks)):
            if s not in names:
                names.append(s)
    return tuple(names)
