"""SunSpec models to ``pymb.map/1`` maps: the converter.

A SunSpec device is a chain of models, each a group of points that may hold
repeating groups (one MPPT module, one curve, one curve point). This module
lays the models' own JSON definitions (``models/model_<id>.json``, copied
unchanged from the SunSpec Alliance's ``models`` repository, Apache-2.0, see
``NOTICE``) out at a device's addresses and writes the map as TOML text,
which :func:`pymb.maps.loads` checks like any other map.

Names are the models' own, each prefixed by its model's name so that models
can meet in one device: ``inverter.W``, ``inverter.W_SF``, ``common.Mn``. A
point of a repeating group is a ``[[block]]`` named by its path
(``mppt.module.DCA``, one channel per module); a repeating group inside a
repeating group gives a block per outer instance (``DERVoltVar.Crv[2].Pt.V``,
1-based). A second model of the same name in one device is ``<name>_2``.

Types: int16/uint16/count/acc16/enum16/bitfield16/sunssf are 16-bit,
int32/uint32/acc32/enum32/bitfield32/ipaddr/float32 32-bit, int64/uint64/
acc64/eui48/float64 64-bit, string a ``string``, ipv6addr ``raw``, pad no
point. A type's not-implemented value (0x8000, 0xFFFF, 0 for accumulators,
NaN, a string all NUL...) is a marker: the point reads None, state
``not_implemented``. A
point's ``sf`` is ``scale_from`` its scale factor point (10^SF), an integer
``sf`` a fixed ``scale``.
"""

from __future__ import annotations

import functools
import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from importlib import resources
from typing import NotRequired, TypedDict

from pymb.maps.point import MapError

__all__ = [
    "MAX_POINT_REGISTERS",
    "NOT_IMPLEMENTED",
    "GroupDef",
    "ModelDef",
    "Placed",
    "PointDef",
    "SymbolDef",
    "map_text",
    "model_def",
    "model_ids",
    "model_length",
    "toml_value",
]

#: The state of a point whose register holds its type's not-implemented value.
NOT_IMPLEMENTED = "not_implemented"
#: A point is read in one request; a longer string is split in parts this long.
MAX_POINT_REGISTERS = 125

# SunSpec type -> (pymb type, not-implemented raw pattern or None, kind)
_TYPES: dict[str, tuple[str, int | tuple[int, ...] | None, str]] = {
    "int16": ("i16", 0x8000, "gauge"),
    "uint16": ("u16", 0xFFFF, "gauge"),
    "count": ("u16", 0xFFFF, "gauge"),
    "acc16": ("u16", 0, "counter"),
    "enum16": ("u16", 0xFFFF, "state"),
    "bitfield16": ("u16", 0xFFFF, "state"),
    "sunssf": ("sunssf", None, "gauge"),
    "int32": ("i32", 0x8000_0000, "gauge"),
    "uint32": ("u32", 0xFFFF_FFFF, "gauge"),
    "acc32": ("u32", 0, "counter"),
    "enum32": ("u32", 0xFFFF_FFFF, "state"),
    "bitfield32": ("u32", 0xFFFF_FFFF, "state"),
    "ipaddr": ("u32", 0, "gauge"),
    "int64": ("i64", 0x8000_0000_0000_0000, "gauge"),
    "uint64": ("u64", 0xFFFF_FFFF_FFFF_FFFF, "gauge"),
    "acc64": ("u64", 0, "counter"),
    # the two first bytes are padding (masked off); pysunspec2 reads all-zero as none too
    "eui48": ("u64", (0xFFFF_FFFF_FFFF, 0), "gauge"),
    # SunSpec's NaN; any other NaN reads no value too, with the state nan
    "float32": ("f32", 0x7FC0_0000, "gauge"),
    "float64": ("f64", 0x7FF8_0000_0000_0000, "gauge"),
    "string": ("string", 0, "text"),  # 0: the empty text (all NUL)
    "ipv6addr": ("raw", None, "gauge"),
}
_MASKS = {"eui48": 0xFFFF_FFFF_FFFF}
_SKIPPED = frozenset({"pad"})
_UNMAPPED = 0xFFFF


class SymbolDef(TypedDict):
    """One symbol of an enum or bitfield point in a SunSpec definition."""

    name: str
    value: int


class PointDef(TypedDict):
    """A point of a SunSpec definition, the keys pymb reads."""

    name: str
    type: str
    size: int
    sf: NotRequired[int | str]
    units: NotRequired[str]
    access: NotRequired[str]
    static: NotRequired[str]
    label: NotRequired[str]
    symbols: NotRequired[list[SymbolDef]]


class GroupDef(TypedDict):
    """A group of a SunSpec definition: its points and inner groups, and
    ``count``, a number (0: as many as the model's length holds) or the
    name of a point of an enclosing group."""

    name: str
    type: NotRequired[str]
    label: NotRequired[str]
    count: NotRequired[int | str]
    points: NotRequired[list[PointDef]]
    groups: NotRequired[list[GroupDef]]


class ModelDef(TypedDict):
    """A SunSpec model's JSON definition, the keys pymb reads."""

    id: int
    group: GroupDef


class _Entry(TypedDict, total=False):
    """A ``[[point]]`` (``address``) or ``[[block]]`` (``first``, ``count``,
    ``stride``) table of the map being written, key by key in TOML order."""

    name: str
    first: int
    count: int
    stride: int
    address: int
    type: str
    encoding: str
    mask: int
    markers: dict[int, str]
    scale: float
    scale_from: str
    values: dict[int, str]
    flags: dict[int, str]
    unit: str
    kind: str
    access: str
    group: str
    description: str
    ref: str


@functools.lru_cache(maxsize=1)
def model_ids() -> tuple[int, ...]:
    """The ids of every SunSpec model pymb knows, ascending."""
    folder = resources.files("pymb.maps.sunspec") / "models"
    return tuple(sorted(int(f.name[6:-5]) for f in folder.iterdir()
                        if f.name.startswith("model_") and f.name.endswith(".json")))


@functools.lru_cache(maxsize=256)
def _def_text(model_id: int) -> str:
    res = resources.files("pymb.maps.sunspec") / "models" / f"model_{model_id}.json"
    return res.read_text(encoding="utf-8")


def model_def(model_id: int) -> ModelDef:
    """The SunSpec definition of ``model_id`` (its JSON, as published), or a
    :class:`MapError` naming the id."""
    if isinstance(model_id, bool) or not isinstance(model_id, int):
        raise MapError(f"a SunSpec model id is a whole number, got {model_id!r}")
    if model_id not in model_ids():
        raise MapError(f"pymb knows no SunSpec model {model_id}", key=str(model_id))
    doc: ModelDef = json.loads(_def_text(model_id))
    return doc


@dataclass(frozen=True)
class Placed:
    """One model in a device: its id, the on-wire address of its ID
    register, its length ``L`` (registers after ID and L), the name its
    points are prefixed with, and, when read, its registers from ID on (the
    counts of repeating groups sized by a point, e.g. ``NPt``, come from
    them; without them such a group has one instance)."""

    id: int
    address: int
    length: int
    prefix: str
    registers: tuple[int, ...] | None = None


def _fixed_length(g: GroupDef) -> int:
    return sum(int(p["size"]) for p in g.get("points", []))


def model_length(model_id: int, repeats: int = 1) -> int:
    """``L`` of ``model_id`` with ``repeats`` instances of each repeating
    group (one of each nested one)."""
    top = model_def(model_id)["group"]

    def size(g: GroupDef, n: int) -> int:
        inner = sum(size(s, _static_count(s, repeats)) for s in g.get("groups", []))
        return n * (_fixed_length(g) + inner)

    return size(top, 1) - 2


def _static_count(g: GroupDef, repeats: int) -> int:
    c = g.get("count", 1)
    if isinstance(c, int):
        return c if c > 0 else repeats
    return 1  # a count a point gives: one instance without the device's registers


def _has_scale_factors(g: GroupDef) -> bool:
    return any(p["type"] == "sunssf" for p in g.get("points", [])) or any(
        _has_scale_factors(s) for s in g.get("groups", []))


class _Layout:
    """Lays one placed model out as map entries."""

    def __init__(self, placed: Placed, entries: list[_Entry]) -> None:
        self.placed = placed
        self.entries = entries
        self.end = placed.address + 2 + placed.length

    def count(self, g: GroupDef, at: int, parents: list[tuple[GroupDef, int]],
              instance_len: int) -> int:
        c = g.get("count", 1)
        if isinstance(c, int) and c > 0:
            return c
        if isinstance(c, int):  # 0: as many as the model's length holds
            return max(0, (self.end - at) // instance_len) if instance_len else 0
        for group, start in reversed(parents):  # a point of an enclosing group names it
            off = start
            for p in group.get("points", []):
                if p["name"] == c:
                    regs = self.placed.registers
                    i = off - self.placed.address
                    if regs is None or i >= len(regs):
                        return 1
                    v = 0 if regs[i] == _UNMAPPED else regs[i]
                    # never more than the model's length holds (a device may say anything)
                    room = max(0, (self.end - at) // instance_len) if instance_len else 0
                    return min(v, room)
                off += int(p["size"])
        raise MapError(f"SunSpec model {self.placed.id}: group {g['name']!r} counts "
                       f"{c!r}, which no enclosing group has")

    def length(self, g: GroupDef, at: int,
               parents: list[tuple[GroupDef, int]]) -> int:
        """Registers of one instance of ``g`` starting at ``at``."""
        n = _fixed_length(g)
        here = [*parents, (g, at)]
        for s in g.get("groups", []):
            one = self.length(s, at + n, here)
            n += self.count(s, at + n, here, one) * one
        return n

    def group(self, g: GroupDef, at: int, path: list[str],
              parents: list[tuple[GroupDef, int]],
              rep: tuple[int, int, int] | None, scope: dict[str, str]) -> int:
        """Entries of one instance of ``g`` at ``at`` (every instance when
        ``rep`` = (instances, stride, index of the repeated name in path));
        returns the instance's length."""
        names = dict(scope)
        off = at
        for p in g.get("points", []):
            names[p["name"]] = ".".join([*path, p["name"]])
        here = [*parents, (g, at)]
        for p in g.get("points", []):
            size = int(p["size"])
            if p["type"] not in _SKIPPED:
                self.point(p, off, path, rep, names)
            off += size
        for s in g.get("groups", []):
            one = self.length(s, off, here)
            n = self.count(s, off, here, one)
            sub = [*path, s["name"]]
            if s.get("count", 1) == 1:
                self.group(s, off, sub, here, rep, names)
            elif n > 0 and rep is None and _has_scale_factors(s):
                for j in range(n):  # a scale factor is one value: a point per instance
                    self.group(s, off + j * one, [*path, f"{s['name']}[{j + 1}]"], here, None,
                               names)
            elif n > 0 and rep is None:
                self.group(s, off, sub, here, (n, one, len(sub) - 1), names)
            elif n > 0 and rep is not None:
                outer, stride, index = rep
                for j in range(outer):
                    named = [*path]
                    named[index] = f"{named[index]}[{j + 1}]"
                    self.group(s, off + j * stride, [*named, s["name"]], here,
                               (n, one, len(named)), names)
            off += n * one
        return off - at

    def point(self, p: PointDef, at: int, path: list[str],
              rep: tuple[int, int, int] | None, names: Mapping[str, str]) -> None:
        typ, marker, kind = _TYPES[p["type"]]
        size = int(p["size"])
        if rep is not None and typ in ("string", "raw"):  # no blocks of text: one point each
            outer, stride, index = rep
            for j in range(outer):
                named = [*path]
                named[index] = f"{named[index]}[{j + 1}]"
                self.point(p, at + j * stride, named, None, names)
            return
        full = ".".join([*path, p["name"]])
        e: _Entry = {"name": full}
        if rep is not None:
            e.update({"first": at, "count": rep[0], "stride": rep[1]})
        else:
            e["address"] = at
        e["type"] = typ
        if typ in ("string", "raw"):
            e["count"] = size
        if typ == "string":
            e["encoding"] = "utf-8"  # as pysunspec2 reads it; ASCII is a part of it
        if p["type"] in _MASKS:
            e["mask"] = _MASKS[p["type"]]
        if marker is not None:
            e["markers"] = {m: NOT_IMPLEMENTED for m in
                            (marker if isinstance(marker, tuple) else (marker,))}
        sf = p.get("sf")
        if isinstance(sf, int) and not isinstance(sf, bool):
            if sf:
                e["scale"] = 10.0 ** sf
        elif isinstance(sf, str):
            e["scale_from"] = names.get(sf, ".".join([self.placed.prefix, sf]))
        symbols = {int(s["value"]): str(s["name"]) for s in p.get("symbols", [])}
        if symbols and p["type"].startswith("enum"):
            e["values"] = symbols
        elif symbols and p["type"].startswith("bitfield"):
            e["flags"] = symbols
        if p.get("units"):
            e["unit"] = str(p["units"])
        if kind != "gauge":
            e["kind"] = kind
        if p.get("access") == "RW":
            e["access"] = "rw"
        static = p.get("static") == "S" and p["type"] != "sunssf"
        e["group"] = "config" if static or p["name"] in ("ID", "L") else "fast"
        label = p.get("label")
        if label:
            e["description"] = str(label)
        e["ref"] = f"SunSpec model {self.placed.id} {'.'.join([*path[1:], p['name']]) or full}"
        if typ == "string" and size > MAX_POINT_REGISTERS:
            for i, start in enumerate(range(0, size, MAX_POINT_REGISTERS)):
                part = e.copy()
                part["count"] = min(MAX_POINT_REGISTERS, size - start)
                if rep is not None:
                    part["first"] = at + start
                else:
                    part["address"] = at + start
                if i:
                    part["name"] = f"{full}_{i + 1}"
                self.entries.append(part)
            return
        self.entries.append(e)


_WIDTHS = {"u16": 1, "i16": 1, "sunssf": 1, "u32": 2, "i32": 2, "f32": 2, "u64": 4, "i64": 4,
           "f64": 4}


def _layout(placed: Placed) -> tuple[list[_Entry], list[str]]:
    """The entries of one placed model that lie inside it (its ``L``), and
    the names of those that do not (a device may implement a shorter model)."""
    top = model_def(placed.id)["group"]
    out: list[_Entry] = []
    lay = _Layout(placed, out)
    lay.group(top, placed.address, [placed.prefix], [], None, {})
    kept: list[_Entry] = []
    left: list[str] = []
    for e in out:
        width = _WIDTHS.get(e["type"]) or int(e["count"])
        if "first" in e:
            fit = (lay.end - e["first"] - width) // e["stride"] + 1
            if fit < e["count"]:
                left.append(e["name"])
                if fit < 1:
                    continue
                e = e.copy()
                e["count"] = fit
        elif e["address"] + width > lay.end:
            left.append(e["name"])
            continue
        kept.append(e)
    names = {e["name"] for e in kept}
    scaled = [e for e in kept if e.get("scale_from", e["name"]) in names]
    left += [e["name"] for e in kept if e.get("scale_from", e["name"]) not in names]
    return scaled, left


def laid_length(placed: Placed) -> int:
    """Registers the points and repeating groups of a placed model take,
    from its ID on, the groups counted as its registers say (at most as
    many as its ``L`` holds)."""
    top = model_def(placed.id)["group"]
    return _Layout(placed, []).length(top, placed.address, [])


def entries_of(placed: Placed) -> list[_Entry]:
    """The map entries (``[[point]]``/``[[block]]`` tables as dicts, a block
    having ``first``) of one placed model, those inside its length ``L``."""
    return _layout(placed)[0]


def left_out(placed: Placed) -> list[str]:
    """The points of a placed model that its length ``L`` leaves out (or
    cuts short, for a block), and those whose scale factor it leaves out."""
    return _layout(placed)[1]


def toml_value(v: object) -> str:
    """``v`` written as a TOML value (text, numbers, booleans, lists, and
    tables with integer keys, written in hex above 255)."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)
    if isinstance(v, list | tuple):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, Mapping):
        def key(k: object) -> str:
            return (f"0x{k:X}" if k > 255 else str(k)) if isinstance(k, int) else json.dumps(k)
        return "{ " + ", ".join(f"{key(k)} = {toml_value(x)}" for k, x in v.items()) + " }"
    raise TypeError(f"no TOML for {type(v).__name__}")


def map_text(models: Sequence[Placed], *, base: int, unit: int = 1, device_id: str = "sunspec",
             manufacturer: str = "", model: str = "", description: str = "",
             end: int | None = None, max_registers: int = 125) -> str:
    """The ``pymb.map/1`` TOML of a device made of ``models`` (in chain
    order), whose ``SunS`` marker is at on-wire address ``base``; ``end`` is
    one past the chain's last register (the end marker's ID and L);
    ``max_registers`` the most the device reads in one request (never
    fewer than the widest point: a point is read in one request)."""
    entries: list[_Entry] = []
    for placed in models:
        entries.extend(entries_of(placed))
    max_registers = max([max_registers, *(_WIDTHS.get(e["type"]) or int(e["count"])
                                          for e in entries)])
    last = end if end is not None else max(
        (m.address + 2 + m.length for m in models), default=base + 2)
    head = {
        "id": device_id, "manufacturer": manufacturer, "model": model,
        "description": description or "SunSpec device: models " +
        ", ".join(f"{m.id} ({m.prefix})" for m in models),
        "ref": "SunSpec Information Models (Apache-2.0, SunSpec Alliance)",
        "default_address": unit, "addresses": [0, 255], "address_base": 0,
        "table": "holding", "order": "ABCD",
    }
    lines = ["# Made by pymb from the SunSpec models' own definitions (pymb.maps.sunspec).",
             'schema = "pymb.map/1"', "", "[device]"]
    lines += [f"{k} = {toml_value(v)}" for k, v in head.items() if v != ""]
    lines += ["", "[device.limits]", f"max_registers = {min(max_registers, 125)}",
              "max_gap = 16",
              f"readable = {{ holding = [[{base}, {min(0xFFFF, max(base, last - 1))}]] }}", "",
              "[groups]", "fast = { interval = 1.0 }", "config = { interval = 0 }"]
    for e in entries:
        lines += ["", "[[block]]" if "first" in e else "[[point]]"]
        lines += [f"{k} = {toml_value(v)}" for k, v in e.items()]
    return "\n".join(lines) + "\n"
