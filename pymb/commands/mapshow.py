"""``pymb map list`` and ``pymb map show ID``: the maps pymb ships, and one
map's points as a table (name, address, table, type, scale and unit,
access, valid range)."""

from __future__ import annotations

import argparse
import os
import shutil
import sys
from typing import Any

from pymb import maps
from pymb.commands._common import print_json
from pymb.devices.mapspec import load_map, near
from pymb.errors import InvalidArgument
from pymb.maps import Map, Point

__all__ = ["add_list_show", "map_rows", "run_list", "run_show", "shipped_or_file", "shipped_rows"]


def add_list_show(sub: Any) -> None:
    """The ``list`` and ``show`` subcommands of ``pymb map``."""
    ls = sub.add_parser("list", help="the maps pymb ships: id, title, source document",
                        description="list the maps pymb ships (usable as a device TYPE "
                                    "without --map): id, title and the document each was "
                                    "written from")
    ls.add_argument("--json", action="store_true", help="print JSON")
    show = sub.add_parser("show", help="a map's points as a table",
                          description="print a map's points as a table: name, address, "
                                      "table, type, scale and unit, access, valid range")
    show.add_argument("map", metavar="ID",
                      help="the id of a map pymb ships (see pymb map list), or a map file")
    show.add_argument("--json", action="store_true", help="print JSON")


def _title(m: Map) -> str:
    d = m.device
    return " ".join(x for x in (d.manufacturer, d.model) if x) or d.description or m.id


def shipped_rows() -> list[dict[str, str]]:
    """``{id, title, ref}`` of every shipped map, by id."""
    out = []
    for ident in sorted(maps.builtin_ids()):
        m = maps.builtin(ident)
        out.append({"id": ident, "title": _title(m), "ref": m.device.ref})
    return out


def _num(x: float) -> str:
    return f"{x:g}" if isinstance(x, float) else str(x)


def _scale(p: Point) -> str:
    parts = []
    if p.scale_from is not None:
        parts.append(f"x10^{p.scale_from}")
    elif p.scale is not None:
        parts.append(f"x{_num(p.scale)}")
    if p.offset is not None:
        parts.append(f"{'+' if p.offset >= 0 else '-'}{_num(abs(p.offset))}")
    if p.unit:
        parts.append(p.unit)
    return " ".join(parts) or "-"


def _type(m: Map, p: Point) -> str:
    t = p.type
    if t in ("string", "raw"):
        t += f"[{p.count}]"
    elif t == "bit":
        t += f" {p.bit}"
    elif t == "bits":
        t += f" {p.shift}+{p.width}"
    if p.mask is not None:
        t += f" & 0x{p.mask:X}"
    return t


def map_rows(m: Map) -> list[dict[str, Any]]:
    """One row per point: ``name``, ``address`` (as the file numbers it;
    a block's first channel, with its channel count and stride), ``table``,
    ``type``, ``scale`` (scale, offset and unit as text), ``access``,
    ``valid`` (``[lo, hi]`` or None)."""
    base = m.device.address_base
    rows = []
    for p in m.points.values():
        address = str(p.address + base)
        if p.block:
            address += f" (+{p.stride} x {p.channels})"
        rows.append({"name": p.name, "address": address, "table": p.table,
                     "type": _type(m, p), "scale": _scale(p), "access": p.access,
                     "valid": list(p.valid) if p.valid is not None else None})
    return rows


def _table(rows: list[list[str]]) -> str:
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    return "\n".join("  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip()
                     for r in rows)


def run_list(args: argparse.Namespace) -> int:
    """``pymb map list``."""
    rows = shipped_rows()
    if args.json:
        print_json(rows)
        return 0
    text = _table([["id", "title", "ref"]] + [[r["id"], r["title"], r["ref"] or "-"]
                                              for r in rows])
    if sys.stdout.isatty():  # a line a map, cut to the terminal (whole when piped)
        width = shutil.get_terminal_size((80, 24)).columns or 80
        text = "\n".join(ln if len(ln) < width else ln[:max(1, width - 2)] + "…"
                          for ln in text.splitlines())
    print(text)
    return 0


def shipped_or_file(ident: str) -> tuple[Map, bool]:
    """The map ``pymb map check|show ID`` names, and whether pymb ships it: a
    file of that name, a shipped map's id, else a file path (``x.toml``,
    ``maps/x``) that cannot be read; a mistyped id gets the closest one."""
    shipped = maps.builtin_ids()
    if not os.path.exists(ident) and ident in shipped:
        return maps.builtin(ident), True
    if os.path.exists(ident) or os.sep in ident or ident.endswith(".toml"):
        return load_map(ident), False
    raise InvalidArgument(f"no shipped map {ident!r} and no such file{near(ident, shipped)} "
                          "(pymb map list shows the shipped maps)")


def run_show(args: argparse.Namespace) -> int:
    """``pymb map show ID``."""
    m, _ = shipped_or_file(args.map)
    rows = map_rows(m)
    if args.json:
        print_json({"id": m.id, "title": _title(m), "ref": m.device.ref, "points": rows})
        return 0
    ref = f" ({m.device.ref})" if m.device.ref else ""
    print(f"{m.id}: {_title(m)}{ref}, {len(rows)} point{'s' if len(rows) != 1 else ''}")
    head = ["name", "address", "table", "type", "scale/unit", "access", "valid"]
    body = [[r["name"], r["address"], r["table"], r["type"], r["scale"], r["access"],
             "-" if r["valid"] is None else f"{_num(r['valid'][0])}..{_num(r['valid'][1])}"]
            for r in rows]
    print(_table([head, *body]))
    return 0
