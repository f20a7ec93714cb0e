"""The point fields of ``pymb.map/1`` (contract section 2): one ``[[point]]``
or ``[[block]]`` table, checked key by key, into a :class:`Point`; and the
checks of text keys the ``[device]`` section shares with points."""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import NoReturn, cast

from pymb.errors import InvalidArgument
from pymb.maps.codec import encode
from pymb.maps.point import VIEWS, DeviceSection, MapError, Point, Value, did_you_mean
from pymb.maps.types import (
    FLOAT_TYPES,
    INTEGER_TYPES,
    ORDER_NAMES,
    REGISTER_TABLES,
    SF_RANGE,
    SUNSSF_NOT_IMPLEMENTED,
    TABLES,
    TYPES,
    normalize_order,
)

__all__ = ["POINT_KEYS", "POINT_NAME", "Ctx", "build_point", "check_view", "marker_pattern",
           "number", "strings"]

POINT_KEYS = ("name", "table", "address", "type", "order", "count", "string_bytes", "encoding",
              "bit", "shift", "width", "scale", "offset", "unit", "description", "ref", "kind",
              "values", "flags", "markers", "access", "valid", "group", "deadband", "precision",
              "example", "when", "min_firmware", "max_writes_per_hour", "scale_from", "mask",
              "view_of")
BLOCK_KEYS = (*(k for k in POINT_KEYS if k != "address"), "first", "stride")
#: A point's name: snake_case by convention (``power_w``); letters of either
#: case, dotted paths and instance numbers too, so that a converted model keeps
#: its own names (SunSpec's ``W``, ``inverter.W``, ``DERVoltVar.Crv[2].Pt.V``).
_WORD = r"[A-Za-z][A-Za-z0-9_-]*(\[[0-9]+\])?"
POINT_NAME = re.compile(rf"{_WORD}(\.{_WORD})*\Z")
_NAME = POINT_NAME
_KINDS = ("gauge", "counter", "state", "text")
_ENCODINGS = ("ascii", "latin-1", "utf-8")
_MAX_CHANNELS = 1000


@dataclass(frozen=True)
class Ctx:
    """Where a check is: the file and the point, for the message."""

    source: str
    point: str | None = None

    def fail(self, key: str | None, message: str) -> NoReturn:
        where = f"point {self.point!r}: " if self.point else ""
        what = f"key {key!r}: " if key and repr(key) not in message else ""
        raise MapError(f"{self.source}: {where}{what}{message}", source=self.source,
                       point=self.point, key=key)


def number(ctx: Ctx, key: str, v: object, *, allow_str: bool = False) -> float:
    """``v`` as a number (a string too when ``allow_str``), or a MapError."""
    if allow_str and isinstance(v, str):
        return 0.0
    if isinstance(v, bool) or not isinstance(v, (int, float)) or v != v:
        ctx.fail(key, f"{key} must be a number, got {v!r}")
    return v


def strings(ctx: Ctx, raw: Mapping[str, object], keys: tuple[str, ...]) -> dict[str, str]:
    """Each of ``keys`` that ``raw`` has ("" for one it has not); fail unless
    each is a string."""
    out: dict[str, str] = {}
    for key in keys:
        v = raw.get(key, "")
        if not isinstance(v, str):
            ctx.fail(key, f"{key} must be a string")
        out[key] = v
    return out


def check_view(ctx: Ctx, view: str, ident: str) -> None:
    """``[device] view``: one of :data:`~pymb.maps.point.VIEWS`, named only
    by the map it is the view of (a view knows that device's registers)."""
    if view and view not in VIEWS:
        ctx.fail("view", f"view must be one of {', '.join(VIEWS)}, got {view!r}"
                 f"{did_you_mean(view, VIEWS)}")
    if view and view != ident:
        ctx.fail("view", f"view {view!r} is pymb's view of its own map (id {view!r}): "
                 f"a map of id {ident!r} cannot name it; delete its view line to read it "
                 "as a plain map")


def _option(ctx: Ctx, key: str, v: object, options: Mapping[str, int | float]) -> object:
    """An option's value where ``v`` names one."""
    if isinstance(v, str):
        if v not in options:
            ctx.fail(key, f"{key} names no option {v!r}{did_you_mean(v, list(options))}")
        return options[v]
    return v


def _int_in(ctx: Ctx, key: str, v: object, lo: int, hi: int) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
        ctx.fail(key, f"{key} must be a whole number {lo}..{hi}, got {v!r}")
    return v


def _keyed(ctx: Ctx, key: str, v: object, lo: int, hi: int) -> dict[int, str]:
    """A ``{ 0xFFFF = "offline" }`` table: integer keys (TOML keys are text) to names."""
    if not isinstance(v, dict):
        ctx.fail(key, f"{key} must be a table such as {{ 0 = \"name\" }}")
    out: dict[int, str] = {}
    for k, name in v.items():
        try:
            n = int(k, 0)
        except ValueError:
            ctx.fail(key, f"{key}: {k!r} is not a whole number (decimal or 0x hex)")
        if not lo <= n <= hi:
            ctx.fail(key, f"{key}: {k} is outside {lo}..{hi} for this type")
        if not isinstance(name, str) or not name:
            ctx.fail(key, f"{key}: the name of {k} must be a non-empty string")
        out[n] = name
    return out


def marker_pattern(text: str) -> tuple[int, int] | None:
    """``(pattern, care mask)`` of a marker key with don't-care digits
    (``"0x7FFFxxxx"``: an ``x`` is 4 don't-care bits in hex, 1 in binary
    ``"0b1xxx"``; ``_`` separates digits), or None when ``text`` has none.
    A ValueError for a digit the base does not have."""
    t = text.strip().replace("_", "").lower()
    if t[:2] not in ("0x", "0b") or "x" not in t[2:]:
        return None
    radix, step = (16, 4) if t[:2] == "0x" else (2, 1)
    pattern = care = 0
    for d in t[2:]:
        pattern <<= step
        care <<= step
        if d != "x":
            pattern |= int(d, radix)
            care |= (1 << step) - 1
    return pattern, care


def _markers(ctx: Ctx, v: object, lo: int, bits: int
             ) -> tuple[dict[int, str], list[tuple[int, int, str]]]:
    """``markers``: exact raw values, and patterns with don't-care bits."""
    if not isinstance(v, dict):
        ctx.fail("markers", "markers must be a table such as { 0xFFFF = \"offline\" }")
    exact: dict[str, str] = {}
    masked: list[tuple[int, int, str]] = []
    full = (1 << bits) - 1
    for k, name in v.items():
        try:
            pm = marker_pattern(k)
        except ValueError:
            ctx.fail("markers", f"markers: {k!r} is neither a whole number nor a pattern such "
                     "as \"0x7FFFxxxx\" (x: a don't-care digit)")
        if pm is None:
            exact[k] = name
            continue
        pattern, care = pm
        if care > full or pattern > full:
            ctx.fail("markers", f"markers: the pattern {k} is wider than the value's {bits} bits")
        if not isinstance(name, str) or not name:
            ctx.fail("markers", f"markers: the name of {k} must be a non-empty string")
        masked.append((pattern, care, name))
    out = _keyed(ctx, "markers", exact, lo, full)
    return {n & full: name for n, name in out.items()}, masked


def _bits_of(n: int) -> list[int]:
    return [b for b in range(n.bit_length()) if n >> b & 1]


def _flags(ctx: Ctx, v: object, bits: int, typ: str) -> dict[int, str]:
    """``flags``: bit numbers in decimal (0 = least significant) to names. A
    key written in hex, binary or octal (``0x0008``) is a mask, as manuals
    print them: refused with the bit it meant (``3``)."""
    if not isinstance(v, dict):
        ctx.fail("flags", "flags must be a table of bit numbers: { 0 = \"fault\", 3 = \"alarm\" }")
    out: dict[int, str] = {}
    for k, name in v.items():
        t = k.strip().lower()
        if t[:2] in ("0x", "0b", "0o"):
            try:
                n = int(t, 0)
            except ValueError:
                ctx.fail("flags", f"flags: {k!r} is not a bit number")
            set_bits = _bits_of(n)
            if len(set_bits) == 1:
                ctx.fail("flags", f"flags: {k} is a mask; flags keys are bit numbers in decimal "
                         f"(0 = least significant): write {set_bits[0]} = \"{name}\"")
            ctx.fail("flags", f"flags: {k} is a mask of bits "
                     f"{', '.join(map(str, set_bits)) or 'none'}; flags keys are bit numbers "
                     "in decimal, one bit each (a field of several bits is a bits point, or "
                     "a point with mask)")
        try:
            n = int(t, 10)
        except ValueError:
            ctx.fail("flags", f"flags: {k!r} is not a bit number (0 = least significant, "
                     "in decimal)")
        if not 0 <= n < bits:
            hint = ""
            if n > 0 and len(_bits_of(n)) == 1:
                hint = f"; if {k} is a mask, it is bit {n.bit_length() - 1}"
            ctx.fail("flags", f"flags: {k} is no bit of a {typ} (bits 0..{bits - 1}){hint}")
        if not isinstance(name, str) or not name:
            ctx.fail("flags", f"flags: the name of bit {k} must be a non-empty string")
        out[n] = name
    return out


def build_point(ctx: Ctx, kind: str, raw: Mapping[str, object], dev: DeviceSection,
                groups: Mapping[str, float], options: Mapping[str, int | float]) -> Point:
    """Check one ``[[point]]``/``[[block]]`` table and make its Point."""
    block = kind == "block"
    known = BLOCK_KEYS if block else POINT_KEYS
    for key in raw:
        if key not in known:
            hint = (" (a [[block]] starts at `first`)" if key == "address" else
                    " (`first` and `stride` are for [[block]]; a point has `address`)"
                    if key in ("first", "stride") else did_you_mean(key, known))
            ctx.fail(key, f"unknown key {key!r}{hint}")
    name = raw.get("name")
    if not isinstance(name, str) or not _NAME.match(name):
        ctx.fail("name", "name must be snake_case or a model's own name (letters, "
                 "digits, _ and -, starting with a letter; dots between such parts, "
                 f"each with an optional [N]), got {name!r}")
    texts = strings(ctx, raw, ("unit", "description", "ref", "min_firmware"))
    table = raw.get("table", dev.table)
    if table not in TABLES:
        ctx.fail("table", f"unknown table {table!r}{did_you_mean(str(table), TABLES)}")
    registers = table in REGISTER_TABLES
    typ = raw.get("type", None if registers else "bool")
    if typ is None:
        ctx.fail("type", "type is required for a register point")
    if not isinstance(typ, str) or typ not in TYPES:
        ctx.fail("type", f"unknown type {typ!r}{did_you_mean(str(typ), list(TYPES))}")
    info = TYPES[typ]
    if (typ == "bool") == registers:
        ctx.fail("type", f"{table} points are type bool" if not registers else
                 "bool is for coil and discrete points; use bit for a bit of a register")

    def only(key: str, types: frozenset[str] | tuple[str, ...], what: str) -> None:
        if key in raw and typ not in types:
            instead = ("; a bits field is given by shift and width"
                       if (key, typ) == ("bit", "bits") else "")
            ctx.fail(key, f"{key} applies to {what} points only, not {typ}{instead}")

    scalable = INTEGER_TYPES | FLOAT_TYPES
    only("string_bytes", ("string",), "string")
    only("encoding", ("string",), "string")
    only("bit", ("bit",), "bit")
    only("shift", ("bits",), "bits")
    only("width", ("bits",), "bits")
    only("scale", scalable, "numeric")
    only("offset", scalable, "numeric")
    only("markers", scalable | {"string"}, "numeric and string")
    only("values", INTEGER_TYPES | {"bit", "bool"}, "integer")
    only("valid", scalable | {"bit", "bits", "bool"}, "numeric")
    only("flags", INTEGER_TYPES - {"sm16"}, "integer")
    only("scale_from", scalable - {"sunssf"}, "numeric")
    only("mask", ("u16", "u32", "u64"), "u16, u32 and u64")

    # registers (bits) one value spans
    if block and typ in ("string", "raw"):
        ctx.fail("type", f"a [[block]] of {typ} is not supported; write one [[point]] each")
    if not block and "count" in raw and typ not in ("string", "raw", "bit", "bits"):
        ctx.fail("count", f"count applies to string, raw, bit and bits points, not {typ} "
                 "(for repeated values, use a [[block]])")
    if info.registers:
        count = info.registers
        if not block and typ in ("bit", "bits") and "count" in raw:
            given = raw["count"]
            if not isinstance(given, int) or given not in (1, 2, 4) or isinstance(given, bool):
                ctx.fail("count", f"count of a {typ} view must be 1, 2 or 4 registers, "
                         f"got {given!r}")
            count = given
    else:
        if "count" not in raw:
            ctx.fail("count", f"count (registers) is required for a {typ} point")
        # a point is read in one request, never split: at most 125 registers ([MB-AP] 6.3)
        count = _int_in(ctx, "count", raw["count"], 1, 125)

    channels, stride = 1, count
    if block:
        channels = _int_in(ctx, "count", _option(ctx, "count", raw.get("count", 1), options),
                           1, _MAX_CHANNELS)
        stride = _int_in(ctx, "stride", raw.get("stride", count), count, 65535)
    key = "first" if block else "address"
    if key not in raw:
        ctx.fail(key, f"{key} is required")
    base = dev.address_base
    number_ = _int_in(ctx, key, raw[key], base, 65535 + base)
    address = number_ - base
    end = address + (channels - 1) * stride + count
    if end > 65536:
        ctx.fail(key, f"address + width runs past 65535 ({address} + {end - address} registers)")

    order = ""
    nbytes = 2 * count if typ not in ("bool", "raw", "string") else 0
    if typ == "string":
        o = raw.get("order", dev.order)
        if o not in (*ORDER_NAMES, "AB", "BA"):
            ctx.fail("order", f"a string's order is one of ABCD, CDAB, BADC, DCBA (or AB, BA), "
                     f"got {o!r}")
        order = "BA" if o in ("BADC", "DCBA", "BA") else "AB"
    elif nbytes:
        o = raw.get("order", dev.order)
        norm = normalize_order(o, nbytes) if isinstance(o, str) else None
        if norm is None:
            ctx.fail("order", f"order {o!r} is not ABCD, CDAB, BADC, DCBA or a permutation of "
                     f"the {nbytes} letters {'ABCDEFGH'[:nbytes]}")
        order = norm
    elif "order" in raw:
        ctx.fail("order", f"order does not apply to {typ} points")

    bit = shift = width = None
    if typ == "bit":
        if "bit" not in raw:
            ctx.fail("bit", "bit (0 = least significant) is required for a bit point")
        bit = _int_in(ctx, "bit", raw["bit"], 0, 16 * count - 1)
    if typ == "bits":
        if "width" not in raw:
            ctx.fail("width", "width (bits in the field) is required for a bits point")
        shift = _int_in(ctx, "shift", raw.get("shift", 0), 0, 16 * count - 1)
        width = _int_in(ctx, "width", raw["width"], 1, 16 * count)
        if shift + width > 16 * count:
            room = "the register's 16 bits" if count == 1 else f"its {count} registers' " \
                f"{16 * count} bits"
            ctx.fail("width", f"shift + width ({shift} + {width} = {shift + width}) exceeds "
                     f"{room}")

    string_bytes = raw.get("string_bytes", "both")
    if string_bytes not in ("both", "high", "low"):
        ctx.fail("string_bytes", f"string_bytes is both, high or low, got {string_bytes!r}")
    encoding = raw.get("encoding", "ascii")
    if encoding not in _ENCODINGS:
        ctx.fail("encoding", f"encoding is one of {', '.join(_ENCODINGS)}, got {encoding!r}"
                 f"{did_you_mean(str(encoding), _ENCODINGS)}")

    scale_from = raw.get("scale_from")
    if scale_from is not None:
        if not isinstance(scale_from, str) or not _NAME.match(scale_from):
            ctx.fail("scale_from", f"scale_from names a point (its scale factor), got "
                     f"{scale_from!r}")
        if "scale" in raw:
            ctx.fail("scale_from", "a point has scale or scale_from, not both")
    mask = raw.get("mask")
    if mask is not None:
        mask = _int_in(ctx, "mask", mask, 1, (1 << 16 * count) - 1)
    view_of = raw.get("view_of")
    if view_of is not None and (not isinstance(view_of, str) or not _NAME.match(view_of)):
        ctx.fail("view_of", f"view_of names another point, got {view_of!r}")
    if view_of == name:
        ctx.fail("view_of", "a point is no view of itself")

    scale = offset = None
    if "scale" in raw:
        scale = float(number(ctx, "scale", _option(ctx, "scale", raw["scale"], options)))
        if scale == 0 or scale != scale or abs(scale) == float("inf"):
            ctx.fail("scale", f"scale must be a finite number other than 0, got {raw['scale']!r}")
    if "offset" in raw:
        offset = float(number(ctx, "offset", _option(ctx, "offset", raw["offset"], options)))
        if offset != offset or abs(offset) == float("inf"):
            ctx.fail("offset", "offset must be finite")

    bits: int = (width or 1) if typ == "bits" else 8 if info.family == "half" else 16 * count
    lo_raw = -(1 << (bits - 1)) if bits else 0
    markers, marker_masks = _markers(ctx, raw.get("markers", {}), lo_raw, bits)
    if typ == "string" and (marker_masks or set(markers) - {0}):
        ctx.fail("markers", "a string's only marker is 0, the empty text (its first "
                 "character NUL): markers = { 0 = \"not_implemented\" }")
    if typ == "sunssf":
        markers.setdefault(SUNSSF_NOT_IMPLEMENTED, "not_implemented")
    for state in (*markers.values(), *(m[2] for m in marker_masks)):
        if state == "value":
            ctx.fail("markers", "'value' is no marker name (it is the state of a value)")
    signed = info.signed and info.family != "float"
    vlo = lo_raw if signed else 0
    vhi = 1 if typ in ("bit", "bool") else (1 << (bits - 1)) - 1 if signed else (1 << bits) - 1
    if typ == "sm16":
        vlo, vhi = -0x7FFF, 0x7FFF
    values = _keyed(ctx, "values", raw.get("values", {}), vlo, vhi)
    flags = _flags(ctx, raw.get("flags", {}), bits, typ)

    access = raw.get("access", "r")
    if access not in ("r", "rw", "w"):
        ctx.fail("access", f"access is r, rw or w, got {access!r}")
    if access != "r" and table not in ("coil", "holding"):
        ctx.fail("access", f"{table} points are read-only (rw and w only on coil and holding)")
    seen: dict[str, int] = {}
    for n, label in values.items() if access != "r" else ():  # a write takes a name
        if label in seen:
            ctx.fail("values", f"values: {label!r} names both {seen[label]} and {n}; a write "
                     "by that name would not know which to send")
        seen[label] = n
    valid = None
    if "valid" in raw:
        v = raw["valid"]
        if not isinstance(v, list) or len(v) != 2:
            ctx.fail("valid", f"valid must be [low, high], got {v!r}")
        lo, hi = (number(ctx, "valid", x) for x in v)
        if lo > hi:
            ctx.fail("valid", f"valid must be [low, high] with low <= high, got {v!r}")
        valid = (lo, hi)
    budget = dev.max_writes_per_hour
    if "max_writes_per_hour" in raw:
        if access == "r":
            ctx.fail("max_writes_per_hour", "max_writes_per_hour applies to writable points "
                     "(access rw or w) only")
        budget = _int_in(ctx, "max_writes_per_hour", raw["max_writes_per_hour"], 1, 1_000_000)
    if access == "r":
        budget = None
    group = raw.get("group")
    if group is not None and (not isinstance(group, str) or group not in groups):
        ctx.fail("group", f"no group {group!r} in [groups]{did_you_mean(str(group), list(groups))}")
    deadband = raw.get("deadband")
    band = None if deadband is None else number(ctx, "deadband", deadband)
    if band is not None and band < 0:
        ctx.fail("deadband", "deadband must be 0 or more")
    given_precision = raw.get("precision")
    precision = (None if given_precision is None
                 else _int_in(ctx, "precision", given_precision, 0, 17))
    kind_ = raw.get("kind", "text" if typ == "string" else "gauge")
    if kind_ not in _KINDS:
        ctx.fail("kind", f"kind is one of {', '.join(_KINDS)}, got {kind_!r}"
                 f"{did_you_mean(str(kind_), _KINDS)}")

    point = Point(
        name=name, table=table, address=address, count=count, type=typ, order=order,
        channels=channels, stride=stride if block else 0, block=block, scale=scale,
        offset=offset, markers=MappingProxyType(markers), marker_masks=tuple(marker_masks),
        scale_from=scale_from, mask=mask, view_of=view_of, values=MappingProxyType(values),
        flags=MappingProxyType(flags), access=access, valid=valid, group=group,
        deadband=None if band is None else float(band), precision=precision,
        unit=texts["unit"], kind=kind_, description=texts["description"],
        ref=texts["ref"], bit=bit, shift=shift, width=width, string_bytes=string_bytes,
        encoding=encoding, example=cast(Value, raw.get("example")),  # checked below
        min_firmware=texts["min_firmware"],
        # the loader checked it: option names to numbers
        when=MappingProxyType(dict(cast(Mapping[str, float], raw.get("when", {})))),
        max_writes_per_hour=budget)
    if "example" in raw:
        _check_example(ctx, point, raw["example"])
    return point


def _check_example(ctx: Ctx, p: Point, example: object) -> None:
    items = example if p.block and isinstance(example, list) else [example]
    if p.block and isinstance(example, list) and len(example) != p.channels:
        ctx.fail("example", f"example has {len(example)} values for {p.channels} channels")
    # a scale_from point's example must fit with some scale factor (its own is another point's)
    sfs: list[int | None] = [None] if p.scale_from is None else list(
        range(SF_RANGE[0], SF_RANGE[1] + 1))
    for item in items:
        if item is None:
            continue
        for i, sf in enumerate(sfs):
            try:
                encode(p, item, current=[0] * p.count, check_access=False, sf=sf)
                break
            except InvalidArgument as e:
                if i == len(sfs) - 1:
                    ctx.fail("example", f"example {item!r}: {e}")

