"""Reading and checking ``pymb.map/1`` files: TOML in, :class:`Map` out.

Every mistake is one :class:`MapError` whose message names the file, the
point and the key, with the closest known key or name ("did you mean ...").
The point fields are file in :mod:`pymb.maps.fields`; this module does the
file's sections, options, name and overlap rules.
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import TypeGuard, cast

from pymb._native import MAX_READ_BITS, MAX_READ_REGISTERS
from pymb.maps.checks import check_channel_names, check_overlaps, check_refs, check_widths
from pymb.maps.fields import Ctx, build_point, check_view, number, strings
from pymb.maps.model import Map
from pymb.maps.point import (
    MAX_GAP,
    DeviceSection,
    Identify,
    Limits,
    MapError,
    Point,
    Timing,
    did_you_mean,
)
from pymb.maps.types import ORDER_NAMES, REGISTER_TABLES, TABLES

__all__ = ["CheckedFile", "configure", "load", "loads"]

SCHEMA = "pymb.map/1"
_TOP = ("schema", "device", "groups", "point", "block", "identify")
_DEVICE = ("id", "manufacturer", "model", "description", "ref", "default_address", "addresses",
           "address_base", "table", "order", "limits", "timing", "options",
           "max_writes_per_hour", "view")
_LIMITS = ("max_registers", "max_bits", "max_gap", "readable", "split_on_exception",
           "single_point_requests", "write_multiple", "mask_write", "ranges")
_RANGE = ("table", "first", "last", "max_registers", "max_bits")
_TIMING = ("response_timeout", "turnaround", "inter_request_gap", "after_connect",
           "offline_after", "offline_retry", "backoff")
#: how a group is polled (``[groups] name = { interval = ..., poll = ... }``)
POLLS = ("interval", "bus", "request")
_IDENTIFY = ("point", "range", "equals", "regex")
_ID = re.compile(r"[a-z0-9][a-z0-9-]*\Z")
_NAME = re.compile(r"[a-z][a-z0-9_]*\Z")
_HEADER = re.compile(r"^[ \t]*\[\[[ \t]*(point|block)[ \t]*\]\]", re.M)


@dataclass(frozen=True)
class CheckedFile:
    """A map file, checked, before its options are applied: what :meth:`Map.configure`
    builds a new map from."""

    source: str
    device: DeviceSection
    limits: Limits
    timing: Timing
    groups: Mapping[str, float]
    entries: tuple[tuple[str, int, Mapping[str, object]], ...]  #: (point|block, index, table)
    identify: tuple[Identify, ...]

    def configure(self, m: Map, given: Mapping[str, object]) -> Map:
        """``m`` (built from this file) with the option values in ``given``
        (numbers or their text)."""
        file = self
        dev = file.device
        options = dict(m.options)
        for name, value in given.items():
            if name not in dev.options:
                raise MapError(f"{file.source}: {dev.id!r} has no option {name!r}"
                               f"{did_you_mean(name, list(dev.options))}",
                               source=file.source, key=name)
            options[name] = _option_value(file.source, dev, name, value)
        try:
            return _build(file, options)
        except MapError as e:
            raise MapError(f"{file.source}: options {options}: {e}", source=file.source,
                           point=e.point, key=e.key) from None


def load(path: str | Path) -> Map:
    """Read and check the map file at ``path``."""
    if not isinstance(path, str | os.PathLike):
        raise MapError(f"a map's path is text or a path, got {path!r}", source=str(path))
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        why = e.strerror if isinstance(e, OSError) and e.strerror else str(e)
        raise MapError(f"{p}: cannot read the map: {why}", source=str(p)) from None
    return loads(text, source=str(p))


def loads(text: str, source: str = "<string>") -> Map:
    """Check a map given as TOML text; ``source`` names it in error messages."""
    if not isinstance(text, str):
        raise MapError(f"{source}: a map is TOML text, got {type(text).__name__}", source=source)
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise MapError(f"{source}: not valid TOML: {e}", source=source) from None
    built: dict[int, Point] = {}
    file = _check_file(doc, source, _HEADER.findall(text), built)
    return _build(file, dict(file.device.options), built)


def configure(m: Map, given: Mapping[str, object]) -> Map:
    """``m`` with the option values in ``given`` (numbers or their text)."""
    return m.configure(given)


def _option_value(source: str, dev: DeviceSection, name: str, value: object) -> int | float:
    default, where = dev.options[name], dev.id if source.startswith("builtin:") else source
    v: int | float
    try:
        if isinstance(value, str):
            v = int(value, 0) if isinstance(default, int) else float(value)
        elif isinstance(value, bool) or not isinstance(value, (int, float)):
            raise TypeError
        elif isinstance(default, int):
            if isinstance(value, float) and not value.is_integer():
                raise TypeError
            v = int(value)
        else:
            v = float(value)
    except (TypeError, ValueError):
        kind = "a whole number" if isinstance(default, int) else "a number"
        raise MapError(f"{where}: option {name!r} must be {kind}, got {value!r}",
                       source=source, key=name) from None
    allowed = dev.option_values.get(name)
    if allowed and v not in allowed:
        raise MapError(f"{where}: option {name!r} must be one of "
                       f"{', '.join(map(str, allowed))}, got {value!r}", source=source, key=name)
    lo, hi = dev.option_ranges.get(name, (-math.inf, math.inf))
    if not lo <= v <= hi:
        raise MapError(f"{where}: option {name!r} must be {lo:g}..{hi:g}, got {value!r}",
                       source=source, key=name)
    return v


def _keys(ctx: Ctx, table: object, known: tuple[str, ...], where: str) -> dict[str, object]:
    if not isinstance(table, dict):
        ctx.fail(None, f"{where} must be a table")
    for key in table:
        if key not in known:
            ctx.fail(key, f"unknown key {key!r} in {where}{did_you_mean(key, known)}")
    return table


def _check_file(doc: dict[str, object], source: str, headers: list[str],
                built: dict[int, Point]) -> CheckedFile:
    ctx = Ctx(source)
    _keys(ctx, doc, _TOP, "the file")
    if "schema" not in doc:
        ctx.fail("schema", f"schema = {SCHEMA!r} is required at the top")
    if doc["schema"] != SCHEMA:
        ctx.fail("schema", f"schema must be {SCHEMA!r}, got {doc['schema']!r}")
    if "device" not in doc:
        ctx.fail("device", "a [device] section with an id is required")
    device, table = _device(ctx, doc["device"])
    limits = _limits(ctx, table.get("limits", {}), device)
    timing = _timing(ctx, table.get("timing", {}))
    groups, polls = _groups(ctx, doc.get("groups", {}))
    if polls:
        timing = dataclasses.replace(timing, polls=polls)
    lists: dict[str, list[dict[str, object]]] = {}
    for kind in ("point", "block"):
        items = doc.get(kind, [])
        if not isinstance(items, list):
            ctx.fail(kind, f"write points as [[{kind}]] tables")
        tables = lists[kind] = []
        for i, item in enumerate(items):
            if not isinstance(item, dict):
                ctx.fail(kind, f"[[{kind}]] number {i + 1} must be a table")
            tables.append(item)
    # File order: tomllib keeps [[point]] and [[block]] apart; the headers say how they mix.
    if sorted(headers) != sorted(["point"] * len(lists["point"]) + ["block"] * len(lists["block"])):
        headers = ["point"] * len(lists["point"]) + ["block"] * len(lists["block"])
    seen = {"point": 0, "block": 0}
    entries: list[tuple[str, int, Mapping[str, object]]] = []
    for kind in headers:
        entries.append((kind, seen[kind], lists[kind][seen[kind]]))
        seen[kind] += 1
    if not entries:
        ctx.fail("point", "the map has no [[point]] or [[block]]")
    file = CheckedFile(source, device, limits, timing, MappingProxyType(groups), tuple(entries), ())
    _check_variants(file, built)
    identify = tuple(_identify(i, raw, file) for i, raw in
                     enumerate(_list(ctx, doc.get("identify", []), "identify")))
    return CheckedFile(source, device, limits, timing, file.groups, file.entries, identify)


def _list(ctx: Ctx, v: object, key: str) -> list[object]:
    if not isinstance(v, list):
        ctx.fail(key, f"write it as [[{key}]] tables")
    return v


def _int(ctx: Ctx, table: Mapping[str, object], key: str, default: int, lo: int, hi: int) -> int:
    v = table.get(key, default)
    if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
        ctx.fail(key, f"{key} must be a whole number {lo}..{hi}, got {v!r}")
    return v


def _device(ctx: Ctx, raw: object) -> tuple[DeviceSection, dict[str, object]]:
    t = _keys(ctx, raw, _DEVICE, "[device]")
    ident = t.get("id")
    if not isinstance(ident, str) or not _ID.match(ident):
        ctx.fail("id", f"device id must match [a-z0-9][a-z0-9-]*, got {ident!r}")
    texts = strings(ctx, t, ("manufacturer", "model", "description", "ref", "view"))
    check_view(ctx, texts["view"], ident)
    addresses = t.get("addresses", [1, 247])
    if (not isinstance(addresses, list) or len(addresses) != 2
            or any(isinstance(a, bool) or not isinstance(a, int) or not 0 <= a <= 255
                   for a in addresses) or addresses[0] > addresses[1]):
        ctx.fail("addresses", f"addresses must be [first, last] within 0..255, got {addresses!r}")
    lo, hi = addresses
    default_address = _int(ctx, t, "default_address", max(lo, 1), lo, hi)
    base = t.get("address_base", 0)
    if base not in (0, 1) or isinstance(base, bool):
        ctx.fail("address_base", f"address_base must be 0 or 1, got {base!r}")
    table = t.get("table", "holding")
    if table not in TABLES:
        ctx.fail("table", f"table must be one of {', '.join(TABLES)}, got {table!r}"
                 f"{did_you_mean(str(table), TABLES)}")
    order = t.get("order", "ABCD")
    if order not in ORDER_NAMES:
        ctx.fail("order", f"device order must be one of {', '.join(ORDER_NAMES)}, got {order!r}")
    options, allowed, ranges = _options(ctx, t.get("options", {}))
    budget = None
    if "max_writes_per_hour" in t:
        budget = _int(ctx, t, "max_writes_per_hour", 0, 1, 1_000_000)
    return DeviceSection(ident, texts["manufacturer"], texts["model"], texts["description"],
                         texts["ref"], default_address, (lo, hi), base, table, order,
                         MappingProxyType(options), MappingProxyType(allowed),
                         MappingProxyType(ranges), budget, texts["view"]), t


def _options(ctx: Ctx, raw: object) -> tuple[dict[str, int | float],
                                             dict[str, tuple[int | float, ...]],
                                             dict[str, tuple[float, float]]]:
    if not isinstance(raw, dict):
        ctx.fail("options", "[device.options] must be a table of name = default")
    options: dict[str, int | float] = {}
    allowed: dict[str, tuple[int | float, ...]] = {}
    ranges: dict[str, tuple[float, float]] = {}
    for name, v in raw.items():
        if not _NAME.match(name):
            ctx.fail(name, f"option name {name!r} must be snake_case")
        if isinstance(v, dict):
            _keys(ctx, v, ("default", "values", "min", "max"), f"option {name!r}")
            vals = v.get("values", [])
            if not isinstance(vals, list) or not all(_is_number(x) for x in vals):
                ctx.fail(name, f"option {name!r}: values must be a list of numbers")
            if vals:
                allowed[name] = tuple(vals)
            lo, hi = v.get("min", -math.inf), v.get("max", math.inf)
            if not (_is_number(lo) and _is_number(hi) and lo <= hi):
                ctx.fail(name, f"option {name!r}: min and max must be numbers, min <= max")
            ranges[name] = (lo, hi)
            v = v.get("default")
            if _is_number(v) and ((vals and v not in vals) or not lo <= v <= hi):
                ctx.fail(name, f"option {name!r}: default {v!r} is not one of its values")
        if not _is_number(v):
            ctx.fail(name, f"option {name!r} must be an int or a float, got {v!r}")
        options[name] = v
    return options, allowed, ranges


def _is_number(v: object) -> TypeGuard[int | float]:
    """An int or a float other than NaN (an infinity is a number: an option's
    unbounded ``max``)."""
    return isinstance(v, (int, float)) and not isinstance(v, bool) and v == v


def _limits(ctx: Ctx, raw: object, dev: DeviceSection) -> Limits:
    t = _keys(ctx, raw, _LIMITS, "[device.limits]")
    readable: dict[str, tuple[tuple[int, int], ...]] = {}
    rd = t.get("readable", {})
    if not isinstance(rd, dict):
        ctx.fail("readable", "readable must be a table: { input = [[0, 79]] }")
    for table, ranges in rd.items():
        if table not in TABLES:
            ctx.fail("readable", f"readable: unknown table {table!r}{did_you_mean(table, TABLES)}")
        out = []
        for r in ranges if isinstance(ranges, list) else [None]:
            base = dev.address_base
            if (not isinstance(r, list) or len(r) != 2 or not all(
                    isinstance(a, int) and not isinstance(a, bool) for a in r)
                    or not base <= r[0] <= r[1] <= 65535 + base):
                ctx.fail("readable", f"readable.{table}: each range is [first, last] "
                         f"within {base}..{65535 + base}, got {r!r}")
            out.append((r[0] - base, r[1] - base))
        readable[table] = tuple(sorted(out))
    flags: dict[str, bool] = {}
    for key, default in (("split_on_exception", True), ("single_point_requests", False),
                         ("mask_write", False)):
        flag = t.get(key, default)
        if not isinstance(flag, bool):
            ctx.fail(key, f"{key} must be true or false")
        flags[key] = flag
    multiple = t.get("write_multiple", "auto")
    if multiple not in ("auto", "always"):
        ctx.fail("write_multiple", f"write_multiple is \"auto\" (FC 06 for one register) or "
                 f"\"always\" (FC 16 for every write), got {multiple!r}")
    return Limits(_int(ctx, t, "max_registers", MAX_READ_REGISTERS, 1, MAX_READ_REGISTERS),
                  _int(ctx, t, "max_bits", MAX_READ_BITS, 1, MAX_READ_BITS),
                  None if "max_gap" not in t else _int(ctx, t, "max_gap", 0, 0, MAX_GAP),
                  MappingProxyType(readable),
                  flags["split_on_exception"], flags["single_point_requests"],
                  multiple, flags["mask_write"],
                  _ranges(ctx, t.get("ranges", []), dev))


def _ranges(ctx: Ctx, raw: object, dev: DeviceSection) -> tuple[tuple[str, int, int, int], ...]:
    """``ranges = [{ first = 0, last = 9, max_registers = 1 }, ...]``: limits
    of requests that touch an address range (on-wire, inclusive)."""
    if not isinstance(raw, list):
        ctx.fail("ranges", "ranges must be a list of tables: "
                 "[{ first = 0, last = 9, max_registers = 1 }]")
    out = []
    base = dev.address_base
    for i, r in enumerate(raw):
        where = f"ranges[{i}]"
        _keys(ctx, r, _RANGE, where)
        table = r.get("table", dev.table)
        if table not in TABLES:
            ctx.fail("ranges", f"{where}: unknown table {table!r}"
                     f"{did_you_mean(str(table), TABLES)}")
        bits = table not in REGISTER_TABLES
        key, other = ("max_bits", "max_registers") if bits else ("max_registers", "max_bits")
        if other in r or key not in r:
            ctx.fail("ranges", f"{where}: a range of {table} {'bits' if bits else 'registers'} "
                     f"gives {key}")
        most = _int(ctx, r, key, 1, 1, MAX_READ_BITS if bits else MAX_READ_REGISTERS)
        first, last = r.get("first"), r.get("last")
        if (any(isinstance(a, bool) or not isinstance(a, int) for a in (first, last))
                or not base <= first <= last <= 65535 + base):
            ctx.fail("ranges", f"{where}: first and last are addresses within "
                     f"{base}..{65535 + base}, first <= last, got {first!r}, {last!r}")
        out.append((table, first - base, last - base, most))
    return tuple(out)


def _timing(ctx: Ctx, raw: object) -> Timing:
    t = _keys(ctx, raw, _TIMING, "[device.timing]")
    d = Timing()  # the defaults
    seconds: dict[str, float] = {}
    offline_after, backoff = d.offline_after, d.backoff
    for key in _TIMING:
        if key not in t:
            continue
        if key == "offline_after":
            offline_after = _int(ctx, t, key, 3, 1, 1_000_000)
            continue
        v = t[key]
        if key == "backoff":
            if not isinstance(v, bool):
                ctx.fail(key, f"backoff must be true or false, got {v!r}")
            backoff = v
            continue
        if not _is_number(v) or not math.isfinite(v) or v < 0 \
                or (key == "response_timeout" and v == 0):
            ctx.fail(key, f"{key} must be a number of seconds above 0, got {v!r}"
                     if key == "response_timeout" else
                     f"{key} must be a number of seconds, 0 or more, got {v!r}")
        seconds[key] = float(v)
    return Timing(response_timeout=seconds.get("response_timeout", d.response_timeout),
                  turnaround=seconds.get("turnaround", d.turnaround),
                  inter_request_gap=seconds.get("inter_request_gap", d.inter_request_gap),
                  after_connect=seconds.get("after_connect", d.after_connect),
                  offline_after=offline_after,
                  offline_retry=seconds.get("offline_retry", d.offline_retry),
                  backoff=backoff)


def _groups(ctx: Ctx, raw: object) -> tuple[dict[str, float], tuple[tuple[str, str], ...]]:
    """The groups' intervals, and how each group not polled every its interval is."""
    if not isinstance(raw, dict):
        ctx.fail("groups", "[groups] must be a table: fast = { interval = 1.0 }")
    groups: dict[str, float] = {}
    polls: list[tuple[str, str]] = []
    for name, g in raw.items():
        if not _NAME.match(name):
            ctx.fail(name, f"group name {name!r} must be snake_case")
        _keys(ctx, g, ("interval", "poll"), f"group {name!r}")
        iv = g.get("interval")
        if not _is_number(iv) or not math.isfinite(iv) or iv < 0:
            ctx.fail("interval", f"group {name!r}: interval must be seconds, 0 or more, got {iv!r}")
        groups[name] = float(iv)
        poll = g.get("poll", "interval")
        if poll not in POLLS:
            ctx.fail("poll", f"group {name!r}: poll must be " + ", ".join(map(repr, POLLS))
                     + f", got {poll!r}")
        if poll != "interval":
            polls.append((name, poll))
    return groups, tuple(polls)


def _entry_name(kind: str, index: int, raw: Mapping[str, object]) -> str:
    name = raw.get("name")
    return name if isinstance(name, str) else f"[[{kind}]] number {index + 1}"


def _when(raw: Mapping[str, object]) -> Mapping[str, object]:
    """An entry's ``when`` (checked: a table of option names to numbers)."""
    when = raw.get("when", {})
    return when if isinstance(when, dict) else {}


def _check_variants(file: CheckedFile, built: dict[int, Point]) -> None:
    """Each entry checks under the options its ``when`` names; two entries
    may share a name only when their ``when`` can never both hold. ``built``
    keeps, by position, the points made under the default options."""
    seen: dict[str, list[Mapping[str, object]]] = {}
    defaults = dict(file.device.options)
    for position, (kind, index, raw) in enumerate(file.entries):
        ctx = Ctx(file.source, _entry_name(kind, index, raw))
        when = raw.get("when", {})
        if not isinstance(when, dict):
            ctx.fail("when", "when must be a table: { option = value }")
        options = dict(file.device.options)
        for k, v in when.items():
            if k not in options:
                ctx.fail("when", f"when: no option {k!r}{did_you_mean(k, list(options))}")
            if not _is_number(v):
                ctx.fail("when", f"when: {k} must be a number, got {v!r}")
            options[k] = v
        point = build_point(ctx, kind, raw, file.device, file.groups, options)
        if options == defaults:
            built[position] = point
        name = _entry_name(kind, index, raw)  # build_point checked it
        for other in seen.get(name, []):
            if not any(k in other and other[k] != v for k, v in when.items()):
                ctx.fail("name", f"the name {name!r} is used twice (two points may share a "
                         "name only with `when` conditions that exclude each other)")
        seen.setdefault(name, []).append(when)


def _build(file: CheckedFile, options: dict[str, int | float],
           built: Mapping[int, Point] | None = None) -> Map:
    points: dict[str, Point] = {}
    for position, (kind, index, raw) in enumerate(file.entries):
        if any(options[k] != v for k, v in _when(raw).items()):
            continue
        name = _entry_name(kind, index, raw)
        if built is not None and position in built:
            points[name] = built[position]
            continue
        ctx = Ctx(file.source, name)
        points[name] = build_point(ctx, kind, raw, file.device, file.groups, options)
    check_refs(file.source, points)
    check_overlaps(file.source, points.values())
    check_widths(file.source, file.limits, points.values())
    check_channel_names(file.source, points)
    return Map(file.source, file.device, file.limits, file.timing, file.groups,
               MappingProxyType(points), file.identify, MappingProxyType(dict(options)), file)


def _identify(i: int, raw: object, file: CheckedFile) -> Identify:
    ctx = Ctx(file.source)
    t = _keys(ctx, raw, _IDENTIFY, f"[[identify]] number {i + 1}")
    names = [_entry_name(kind, index, r) for kind, index, r in file.entries]
    point = t.get("point")
    if point not in names:
        ctx.fail("point", f"[[identify]] number {i + 1}: no point {point!r}"
                 f"{did_you_mean(str(point), names)}")
    rules = [k for k in ("range", "equals", "regex") if k in t]
    if len(rules) != 1:
        ctx.fail("range", f"[[identify]] number {i + 1} needs exactly one of range, equals, regex")
    rng = t.get("range")
    if rng is not None:
        if not isinstance(rng, list) or len(rng) != 2 or not all(map(_is_number, rng)) \
                or rng[0] > rng[1]:
            ctx.fail("range", f"range must be [low, high], got {rng!r}")
        rng = (float(rng[0]), float(rng[1]))
    regex = t.get("regex")
    if regex is not None:
        types = {r.get("type") for _, _, r in file.entries if r.get("name") == point}
        if types != {"string"}:
            ctx.fail("regex", f"[[identify]] number {i + 1}: regex needs a string point; "
                     f"{point!r} is not one")
        try:
            re.compile(cast(str, regex))  # another type: a TypeError, said below
        except (re.error, TypeError) as e:
            ctx.fail("regex", f"regex {regex!r} does not compile: {e}")
    equals = t.get("equals")
    if equals is not None and not isinstance(equals, str):
        equals = number(ctx, "equals", equals)
    return Identify(str(point), rng, equals, cast(str | None, regex))
