"""SunSpec on the command line: the ``sunspec[:ADDRESS][,name=...]`` device of
``pymb read``, ``watch`` and ``log`` (its map is built from the models the
device has, found when the command starts), and ``pymb map probe --sunspec``,
which prints the model chain and can save the device's map."""

from __future__ import annotations

import argparse
import os
import sys
from typing import Any

from pymb import maps
from pymb.commands._common import interruptible, make_client, print_json
from pymb.commands.maptext import printable
from pymb.devices.mapspec import MapTarget
from pymb.devices.spec import parse_address, split_spec
from pymb.errors import InvalidArgument
from pymb.maps import MapError
from pymb.maps.sunspec import Discovery, discover, model_def

__all__ = ["KIND", "discover_device", "is_sunspec", "probe", "sunspec_target"]

#: The device type of a SunSpec device whose map is found on the device.
KIND = "sunspec"


def is_sunspec(spec: str) -> bool:
    """Whether the device ``spec`` names a SunSpec device (``sunspec:1``)."""
    return split_spec(spec)[0] == KIND


def _unit(spec: str) -> tuple[int, str]:
    _, addr, opts = split_spec(spec)
    unit = 1 if addr is None else parse_address(addr, spec)
    if not 0 <= unit <= 255:
        raise InvalidArgument(f"{spec!r}: a SunSpec device's address is its unit id, "
                              f"0..255, got {unit}")
    name = ""
    for key, eq, value in opts:
        if key != "name" or not eq or not value:
            raise InvalidArgument(f"{spec!r}: a sunspec device takes only name=...; its "
                                  "points come from the models the device has")
        name = value
    return unit, name


def discover_device(args: argparse.Namespace, unit: int) -> Discovery:
    """Connect as the arguments say and find the SunSpec device ``unit``'s models."""
    client = make_client(args)

    def io() -> Discovery:
        with client:
            return discover(lambda a, n: client.read_holding_registers(a, n, slave=unit))

    return interruptible(io)


def _map(found: Discovery, unit: int, spec: str) -> tuple[maps.Map, str]:
    if not found.models:
        raise InvalidArgument(f"{spec!r}: the device has no SunSpec model pymb knows "
                              f"({'; '.join(found.notes) or 'no models'})")
    text = found.text(unit)
    try:
        return maps.loads(text, source=f"sunspec:{unit}"), text
    except MapError as e:  # a model pymb converts but the device sizes oddly
        raise InvalidArgument(f"sunspec:{unit}: the device's models do not make a map: "
                              f"{e}") from None


def sunspec_target(args: argparse.Namespace, spec: str) -> tuple[MapTarget, str]:
    """The SunSpec device ``spec`` names, its map found on the device, and
    the map's text."""
    unit, name = _unit(spec)
    found = discover_device(args, unit)
    m, text = _map(found, unit, spec)
    for note in found.notes:  # what the map leaves out, said once, beside the output
        print(f"pymb: {spec}: {note}", file=sys.stderr)
    return MapTarget(m, unit, name or f"sunspec-{unit}", {}), text


def _summary(found: Discovery, unit: int, m: maps.Map) -> dict[str, Any]:
    models: list[dict[str, Any]] = []
    for p in found.models:
        prefix = p.prefix + "."
        models.append({"id": p.id, "name": p.prefix, "address": p.address, "length": p.length,
                       "label": str(model_def(p.id)["group"].get("label", "")),
                       "points": sum(1 for n in m.points if n.startswith(prefix))})
    for mid, address, length in found.skipped:
        models.append({"id": mid, "name": None, "address": address, "length": length,
                       "skipped": "pymb does not know this model"})
    models.sort(key=lambda x: int(x["address"]))
    return {"unit": unit, "base": found.base, "end": found.end, "map_id": m.id,
            "manufacturer": found.manufacturer, "model": found.model, "models": models,
            "points": len(m.points), "notes": list(found.notes)}


def probe(args: argparse.Namespace) -> int:
    """``pymb map probe --sunspec ADDRESS [--save FILE]``."""
    unit = args.address
    if not 0 <= unit <= 255:
        raise InvalidArgument(f"ADDRESS must be the device's unit id, 0..255, got {unit}")
    save = getattr(args, "save", None)
    if save and os.path.lexists(save):
        raise InvalidArgument(f"--save {save}: the file exists; pymb does not overwrite it")
    found = discover_device(args, unit)
    m, text = _map(found, unit, f"sunspec:{unit}")
    info = _summary(found, unit, m)
    if save:
        try:
            with open(save, "x", encoding="utf-8") as f:
                f.write(text)
        except OSError as e:
            raise InvalidArgument(f"--save {save}: {e.strerror or e}") from None
        info["saved"] = save
    if args.json:
        print_json(info)
        return 0
    who = printable(" ".join(x for x in (found.manufacturer, found.model) if x))
    print(f"SunSpec device, unit {unit}: 'SunS' at holding {found.base}"
          + (f"; {who}" if who else ""))
    for x in info["models"]:
        if x["name"] is None:
            print(f"  model {x['id']:<5} at {x['address']}, L {x['length']}: skipped, pymb "
                  "does not know this model")
        else:
            print(f"  model {x['id']:<5} at {x['address']}, L {x['length']}: {x['name']} "
                  f"({x['label']}), {x['points']} points")
    print(f"  end at {found.end - 2}")
    for note in found.notes:
        if "skipped: pymb does not know it" not in note:  # those are in the list above
            print(f"  note: {note}")
    print(f"map {m.id}: {len(m.points)} points"
          + (f", saved to {save}" if save else "; --save FILE writes it"))
    return 0
