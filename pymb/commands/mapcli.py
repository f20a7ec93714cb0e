"""What the commands share for device maps: ``--map FILE`` and a reading
of a map device as a table or JSON (the device syntax for a map's id is
:mod:`pymb.devices.mapspec`'s)."""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Mapping
from typing import Any

from pymb.maps import Map

__all__ = ["add_map_arg", "map_json", "render_map"]


def add_map_arg(p: argparse.ArgumentParser, *, group: bool = False) -> None:
    """``--map FILE``, repeatable; with ``group``, also ``--group NAME``."""
    p.add_argument("--map", action="append", default=[], metavar="FILE", dest="maps",
                   help="a device map (pymb.map/1): its device.id becomes a device TYPE "
                        "(repeatable; the shipped maps need none)")
    if group:
        p.add_argument("--group", metavar="NAME",
                       help="a device read through a map: only the points of this polling "
                            "group (default: every readable point)")


def _text(m: Map, name: str, value: Any, state: Any) -> str:
    p = m.points[name]
    if value is None:
        return str(state).replace("_", " ")
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        text = f"{value:.{p.precision}f}" if p.precision is not None else f"{value:g}"
    elif isinstance(value, int) and p.values and value in p.values:
        text = f"{value} ({p.values[value]})"
    elif isinstance(value, int) and p.flags:
        names = [n for bit, n in sorted(p.flags.items()) if value >> bit & 1]
        text = f"0x{value:04X}" + (f" ({', '.join(names)})" if names else "")
    else:
        text = str(value)
    return f"{text} {p.unit}".rstrip()


def render_map(m: Map, values: Mapping[str, Any], states: Mapping[str, Any]) -> str:
    """A reading as lines ``name  value unit``; a block as one line per channel."""
    rows: list[tuple[str, str]] = []
    for name, v in values.items():
        s = states.get(name)
        if isinstance(v, list) and m.points[name].block:
            for c, (cv, cs) in enumerate(zip(v, s or [None] * len(v), strict=True), 1):
                rows.append((f"{name}[{c}]", _text(m, name, cv, cs)))
        else:
            rows.append((name, _text(m, name, v, s)))
    width = max((len(n) for n, _ in rows), default=0)
    return "\n".join(f"{n:<{width}}  {t}" for n, t in rows)


def map_json(values: Mapping[str, Any], states: Mapping[str, Any]) -> dict[str, Any]:
    """A reading for JSON: values (None where there is none) and their states."""
    def clean(v: Any) -> Any:
        if isinstance(v, float) and not math.isfinite(v):
            return None
        if isinstance(v, list):
            return [clean(x) for x in v]
        return v

    out = {"values": {k: clean(v) for k, v in values.items()},
           "states": dict(states)}
    json.dumps(out, allow_nan=False)  # fails here, not half-way through printing
    return out
