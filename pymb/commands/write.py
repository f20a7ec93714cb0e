"""``pymb write DEVICE POINT=VALUE ...``: write points of a map device,
checked before anything is sent and read back.

Prints one line per point, ``POINT: BEFORE -> AFTER UNIT``; ``--dry-run``
prints the requests it would send and sends nothing, not even a read. Exit
codes: 0 every value applied; 2 refused before anything was sent; 3 the
device refused, did not answer, or did not apply; 4 the connection failed.
"""

from __future__ import annotations

import argparse
import struct
import sys
from typing import Any

from pymb import maps
from pymb.commands._common import add_connection_args, add_map_arg, interruptible, make_client
from pymb.commands.maptext import number_text, printable
from pymb.devices.mapdevice import MapDevice
from pymb.devices.mapspec import map_types, parse_map_device, unknown_device
from pymb.devices.mapwrite import Outcome, resolve
from pymb.errors import InvalidArgument, WriteNotApplied
from pymb.maps import Point

__all__ = ["add_arguments", "parse_value", "run"]

_TRUE = ("true", "on", "1")
_FALSE = ("false", "off", "0")


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Arguments of ``pymb write``."""
    p.add_argument("device", metavar="DEVICE",
                   help="TYPE[:ADDRESS][,key=value...]: a map's id (a shipped map's, or a "
                        "--map FILE's)")
    p.add_argument("values", metavar="POINT=VALUE", nargs="+",
                   help="a number, an enum name from the point's values, true/false (or "
                        "1/0) for a bit or coil, text for a string point; a block's channel "
                        "as name_N=VALUE")
    add_connection_args(p)
    add_map_arg(p)
    p.add_argument("--dry-run", action="store_true",
                   help="check everything and print each request; send nothing, not even "
                        "a read")
    p.add_argument("--no-verify", action="store_true",
                   help="do not read the points back after writing")


def parse_value(p: Point, text: str) -> object:
    """The value ``text`` gives point ``p``: a number, an enum name, true/false
    for a bit or coil, text for a string, comma-separated registers for raw."""
    if p.type == "string":
        return text
    low = text.strip().lower()
    if p.type in ("bool", "bit"):
        if low in _TRUE:
            return True
        if low in _FALSE:
            return False
        if not p.values:
            raise InvalidArgument(f"point {p.name!r}: true or false is needed, got {text!r}")
    if p.type == "raw":
        try:
            return [int(x, 0) for x in text.split(",")]
        except ValueError:
            raise InvalidArgument(f"point {p.name!r}: registers as 1,2,3 are needed, "
                                  f"got {text!r}") from None
    try:
        return int(low, 0)
    except ValueError:
        pass
    try:
        return float(low)
    except ValueError:
        return text  # an enum name, or refused by the point's check with its own message


def _items(args: argparse.Namespace, m: maps.Map) -> dict[str, object]:
    out: dict[str, object] = {}
    for item in args.values:
        name, eq, text = item.partition("=")
        name = name.strip()
        if not eq or not name:
            raise InvalidArgument(f"{item!r}: write values as POINT=VALUE")
        if name in out:
            raise InvalidArgument(f"{name!r} is given twice")
        _, p = resolve(m, name)
        try:
            out[name] = parse_value(p, text)
        except InvalidArgument as e:  # named by its device, as the map's own checks are
            raise InvalidArgument(f"{m.id}: {e}") from None
    return out


def _text(p: Point, value: Any) -> str:
    if value is None:
        return "?"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        if p.precision is not None:
            return f"{value:.{p.precision}f}"
        short = f"{value:g}"  # 50 for 50.0; but 123457 for an f32's 123456.78: say its digits
        return short if _same(p, short, value) else number_text(p, value)
    return printable(value)


def _same(p: Point, text: str, value: float) -> bool:
    """Whether ``text`` gives ``value`` back (in the point's own type, for f16 and f32)."""
    code = {"f16": "e", "f32": "f"}.get(p.type)
    try:
        return (struct.pack(code, float(text)) == struct.pack(code, value) if code
                else float(text) == value)
    except OverflowError:  # rounded up past the type's largest
        return False


def _line(m: maps.Map, o: Outcome) -> str:
    _, p = resolve(m, o.name)
    after = _text(p, o.after) if o.applied is not None else \
        f"{_text(p, o.requested)} (not read back)"
    note = "" if o.applied is not False else " (not applied)"
    return f"{o.name}: {_text(p, o.before)} -> {after} {p.unit}".rstrip() + note


def run(args: argparse.Namespace) -> int:
    """Check, write, read back; print each point."""
    known = map_types(args.maps or [], views=True)
    target = parse_map_device(args.device, known)
    if target is None:
        raise unknown_device(args.device, list(known))
    m = target.map
    values = _items(args, m)
    client = make_client(args, resolve=not args.dry_run)  # a dry run may be made offline
    dev = MapDevice(client, m, target.address, baudrate=args.baud)
    plan = dev.plan_write(values)  # everything checked before the line is opened
    if args.dry_run:
        for r in plan:
            print(r.describe())
        return 0
    items = [(n, None, v) for n, v in values.items()]
    opened: list[bool] = []

    def io() -> list[Outcome]:
        with client:
            opened.append(True)
            return dev.write_points(items, verify=not args.no_verify, before=True)

    try:
        outcomes = interruptible(io)
    except KeyboardInterrupt:  # exit 130; say what the device may hold now
        it = "it" if len(values) == 1 else "them"
        print("pymb write: interrupted; " + (
            f"{', '.join(values)} may or may not have been written: read {it} to know"
            if opened else "nothing was sent"), file=sys.stderr)
        raise
    except WriteNotApplied as e:
        for o in e.outcomes:
            print(_line(m, o))
        raise
    for o in outcomes:
        print(_line(m, o))
    return 0
