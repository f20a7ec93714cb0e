"""``pymb map``: check a device map, probe a device's registers, list the
shipped maps or show one's points (:mod:`pymb.commands.mapshow`).

``pymb map check FILE`` validates a map and prints each group's read plan
with its predicted wire time. ``pymb map probe ADDRESS TABLE:START:COUNT``
reads raw registers and prints, for each register it starts at, every type
and byte order side by side: the answer to "which byte order is my meter?".
"""

from __future__ import annotations

import argparse

from pymb import maps
from pymb._native import MAX_READ_REGISTERS
from pymb.commands import sunspeccli
from pymb.commands._common import add_connection_args, interruptible, make_client, print_json
from pymb.commands.mapshow import add_list_show, run_list, run_show, shipped_or_file
from pymb.errors import IllegalDataAddress, InvalidArgument
from pymb.jsonvalue import nan_to_null
from pymb.maps import Point
from pymb.maps.codec import decode_one
from pymb.maps.device_plan import map_planner
from pymb.maps.planner import Line
from pymb.maps.types import ORDER_NAMES, normalize_order
from pymb.wire import DEFAULT_BAUD, bits_per_char

__all__ = ["add_arguments", "interpretations", "run"]


def add_arguments(p: argparse.ArgumentParser) -> None:
    """``pymb map check|probe``."""
    sub = p.add_subparsers(dest="map_command", metavar="check|probe|list|show")
    check = sub.add_parser("check", help="validate a map; print each group's plan and "
                                         "predicted wire time",
                           description="validate a map; print each group's plan and "
                                       "predicted wire time")
    check.add_argument("file", metavar="FILE",
                       help="a map file, or the id of a map pymb ships (e.g. hub)")
    check.add_argument("--baud", type=int, default=DEFAULT_BAUD,
                       help=f"line speed the plans are priced at (default {DEFAULT_BAUD})")
    check.add_argument("--parity", default="N", choices=["N", "E", "O"],
                       help="parity the plans are priced with (default N)")
    probe = sub.add_parser("probe", help="raw registers beside every type and byte order; "
                                         "with --sunspec, a SunSpec device's models",
                           description="read raw registers and print every type and byte "
                                       "order interpretation side by side; with --sunspec, "
                                       "find a SunSpec device's models and build its map")
    probe.add_argument("address", type=int, metavar="ADDRESS", help="the device's unit id")
    probe.add_argument("what", metavar="TABLE:START:COUNT", nargs="?",
                       help="holding or input (h, i), the first register (on the wire, "
                            "from 0) and how many (1..125), e.g. input:0:4")
    probe.add_argument("--sunspec", action="store_true",
                       help="find 'SunS' at 40000, 0 or 50000, walk the model chain and "
                            "build the device's map")
    probe.add_argument("--save", metavar="FILE",
                       help="with --sunspec: write the device's map to FILE (a new file)")
    add_connection_args(probe)
    probe.add_argument("--json", action="store_true", help="print JSON")
    add_list_show(sub)


def _plural(n: int, word: str) -> str:
    return f"{n} {word}" + ("" if n == 1 else "s")


def _check(args: argparse.Namespace) -> int:
    m, shipped = shipped_or_file(args.file)
    if not shipped and m.id in maps.builtin_ids():  # --map and a configuration's maps refuse it
        raise InvalidArgument(f"{args.file}: device id {m.id!r} is a device pymb ships; "
                              "give the map another id")
    planner, mi = map_planner(m, Line(args.baud, bits_per_char(args.parity)))
    what = " ".join(x for x in (m.device.manufacturer, m.device.model) if x)
    print(f"{args.file}: {m.id}{f' ({what})' if what else ''}: "
          f"{_plural(len(m.points), 'point')}, {_plural(len(m.groups), 'group')}: valid")
    groups: list[str | None] = [*m.groups, None]
    for g in groups:
        chosen = [i for i, p in enumerate(mi.points) if p.group == g]
        if g is None and not chosen:
            continue
        interval = m.groups.get(g) if g is not None else None
        polled = m.polled(g) if g is not None else "request"
        when = ("read on request" if polled == "request" else
                "at the bus's interval" if polled == "bus" else
                "read once when the device appears" if interval == 0 else
                f"every {interval:g} s")
        print(f"\ngroup {g or '(none)'}: {_plural(len(chosen), 'point')}, {when}")
        if chosen:
            plan = planner.plan(mi.wanted(chosen))
            print("  " + plan.explain().replace("\n", "\n  "))
    return 0


def _where(text: str) -> tuple[str, int, int]:
    parts = text.split(":")
    names = {"h": "holding", "i": "input", "holding": "holding", "input": "input"}
    if len(parts) != 3 or parts[0].lower() not in names:
        raise InvalidArgument(f"{text!r}: give TABLE:START:COUNT, TABLE holding or input "
                              "(h, i), e.g. input:0:4")
    try:
        start, count = int(parts[1], 0), int(parts[2], 0)
    except ValueError:
        raise InvalidArgument(f"{text!r}: START and COUNT are whole numbers") from None
    if not 0 <= start <= 0xFFFF or not 1 <= count <= MAX_READ_REGISTERS or start + count > 0x10000:
        raise InvalidArgument(f"{text!r}: START is 0..65535 and COUNT "
                              f"1..{MAX_READ_REGISTERS}, within the address space")
    return names[parts[0].lower()], start, count


def _fmt(v: object) -> str:
    if v is None:
        return "nan"
    if isinstance(v, float):
        return f"{v:.7g}"
    return str(v)


_KINDS = ((1, ("u16", "i16", "f16")), (2, ("u32", "i32", "f32")), (4, ("u64", "i64", "f64")))


def _orders(width: int) -> tuple[str, ...]:
    return ("AB", "BA") if width == 1 else ORDER_NAMES


def interpretations(regs: list[int]) -> list[dict[str, object]]:
    """For each register a value may start at: the 16-, 32- and 64-bit
    readings in every named order, decoded by the maps' own codec (None for
    NaN), and the text from there on."""
    out: list[dict[str, object]] = []
    for i in range(len(regs)):
        row: dict[str, object] = {"offset": i, "hex": f"0x{regs[i]:04X}"}
        for width, kinds in _KINDS:
            if i + width > len(regs):
                continue
            for order in _orders(width):
                perm = order if width == 1 else normalize_order(order, 2 * width) or ""
                for kind in kinds:
                    p = Point("probe", "holding", 0, width, kind, order=perm)
                    row[f"{kind}_{order}"] = decode_one(p, regs[i:i + width])[0]
        text = bytes(b for r in regs[i:] for b in (r >> 8, r & 0xFF))
        row["text"] = text.split(b"\0")[0].decode("latin-1")
        out.append(row)
    return out


def _probe(args: argparse.Namespace) -> int:
    if args.sunspec:
        if args.what is not None:
            raise InvalidArgument("--sunspec finds the registers itself: give ADDRESS only")
        return sunspeccli.probe(args)
    if args.save:
        raise InvalidArgument("--save is for --sunspec (the SunSpec device's map)")
    if args.what is None:
        raise InvalidArgument("give TABLE:START:COUNT after ADDRESS (e.g. input:0:4), "
                              "or --sunspec")
    table, start, count = _where(args.what)
    if not 1 <= args.address <= 255:
        raise InvalidArgument(f"ADDRESS must be the device's unit id, 1..255, got {args.address}"
                              + (" (0 is broadcast, which no device answers)"
                                 if args.address == 0 else ""))
    client = make_client(args)

    def io() -> list[int]:
        with client:
            read = (client.read_holding_registers if table == "holding"
                    else client.read_input_registers)
            try:
                return list(read(start, count, slave=args.address))
            except IllegalDataAddress as e:
                raise IllegalDataAddress(f"{e}; the device lacks some of {table} registers "
                                         f"{start}..{start + count - 1}: probe fewer",
                                         code=e.code) from None

    regs = interruptible(io)
    rows = interpretations(regs)
    if args.json:
        print_json({"table": table, "start": start, "registers": regs,
                    "rows": nan_to_null(rows)})
        return 0
    print(f"{table} registers {start}..{start + count - 1} of unit {args.address}: "
          + " ".join(f"{r:04X}" for r in regs))
    for r in rows:
        offset = int(str(r["offset"]))
        print(f"\n{table} {start + offset} ({r['hex']})")
        for width, kinds in _KINDS:
            for order in _orders(width):
                keys = [f"{k}_{order}" for k in kinds]
                if keys[0] not in r:
                    continue
                cells = "  ".join(f"{k} {_fmt(r[key]):>22}" for k, key in zip(kinds, keys,
                                                                                strict=True))
                print(f"  {order:<5} {cells}")
        if r["text"]:
            print(f"  text  {r['text']!r}")
    return 0


def run(args: argparse.Namespace) -> int:
    """``pymb map check`` or ``pymb map probe``."""
    if args.map_command == "check":
        return _check(args)
    if args.map_command == "probe":
        return _probe(args)
    if args.map_command == "list":
        return run_list(args)
    if args.map_command == "show":
        return run_show(args)
    raise InvalidArgument("give a subcommand: pymb map check FILE, pymb map probe "
                          "ADDRESS TABLE:START:COUNT --port PATH, pymb map list, or "
                          "pymb map show ID")

