"""``pymb export FILE.sqlite --csv OUT``: get logged data back out, long (one
row per value) or wide (one row per sample, a column per value).

Never destroys anything: the CSV is written to a temporary file beside OUT
and renamed over it only when complete; OUT may not be the database itself;
an existing OUT that is not a CSV written by pymb is kept unless ``--force``.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
from collections.abc import Callable
from functools import partial
from typing import IO

from pymb.commands._data import (
    check_database,
    device_name,
    parse_channels,
    parse_times,
    readable_database,
)
from pymb.devices.mapspec import load_map
from pymb.devices.spec import closest
from pymb.errors import InvalidArgument
from pymb.maps import Map
from pymb.store import CSV_COLUMNS, LAYOUTS, export_csv, map_point_names, quantities
from pymb.store.commands import WRITE_COLUMNS, export_writes
from pymb.store.export import WIDE_HEAD
from pymb.store.files import write_beside
from pymb.store.schema import HUB_STRIDE


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Arguments of ``pymb export``."""
    p.add_argument("database", help="a database written by pymb log / pymb demo")
    p.add_argument("--csv", metavar="OUT",
                   help="write CSV here ('-' for stdout; required but with --writes)")
    p.add_argument("--writes", action="store_true",
                   help="export the record of writes (the writes view) instead of the samples "
                        "(to stdout without --csv)")
    p.add_argument("--layout", choices=LAYOUTS, default="long",
                   help="long: a row per value, with its state (default); wide: a row per "
                        "sample, a column per value (QUANTITY, or QUANTITY_CHANNEL for a hub)")
    p.add_argument("--device", metavar="DEVICE",
                   help="only this device: TYPE[:ADDRESS] as logged (e.g. hub:250) or its "
                        "name (e.g. hub-250)")
    p.add_argument("--since", help="only data from this time on (ISO 8601, UTC unless it "
                                   "says otherwise)")
    p.add_argument("--until", help="only data before this time (ISO 8601)")
    p.add_argument("--channel", metavar="CHANNELS",
                   help="only these hub channels, e.g. 3 or 1-10,40 (leaves out what has no "
                        "channel: a CoolPro)")
    p.add_argument("--quantity", metavar="NAMES",
                   help="only these quantities, e.g. temperature_c or "
                        "temperature_c,humidity_pct")
    p.add_argument("--events", action="store_true", help="include the events (faults etc.)")
    p.add_argument("--map", action="append", default=[], metavar="FILE", dest="maps",
                   help="decode a map device with this map (pymb.map/1) instead of the copy "
                        "of its map that the database keeps (repeatable)")
    p.add_argument("--force", action="store_true",
                   help="overwrite OUT even if it is not a CSV written by pymb")


def _is_pymb_csv(path: str) -> bool:
    try:
        with open(path, encoding="utf-8", newline="") as f:
            first = f.readline().rstrip("\r\n")
    except (OSError, UnicodeDecodeError):
        return False
    return first in (",".join(CSV_COLUMNS), ",".join(WRITE_COLUMNS)) or \
        first.startswith(",".join(WIDE_HEAD) + ",")


def _given_maps(files: list[str]) -> dict[str, Map]:
    given: dict[str, Map] = {}
    for path in files:
        m = load_map(path)
        if m.id in given:
            raise InvalidArgument(f"--map {path}: device id {m.id!r} is given twice")
        given[m.id] = m
    return given


def _quantities(spec: str | None, points: list[str]) -> list[str] | None:
    if spec is None:
        return None
    known = list(dict.fromkeys([*quantities("coolpro"), *quantities("hub"), *points]))
    out = [q.strip() for q in spec.split(",") if q.strip()]
    if not out:
        raise InvalidArgument(f"--quantity needs names, e.g. temperature_c; got {spec!r}")
    for q in out:
        if q not in known:
            raise InvalidArgument(f"unknown --quantity {q!r}{closest(q, known)}")
    return out


def run(args: argparse.Namespace) -> int:
    """Export; prints how many rows went out."""
    since, until = parse_times(args.since, args.until)
    if args.writes:
        others = [f for f, on in (("--layout wide", args.layout != "long"), ("--device",
                  args.device), ("--channel", args.channel), ("--quantity", args.quantity),
                  ("--events", args.events), ("--map", args.maps)) if on]
        if others:
            raise InvalidArgument(f"--writes exports every write; {others[0]} is for samples")
        check_database(args.database)
        args.csv = args.csv or "-"
        export: Callable[[IO[str]], int] = partial(export_writes, args.database, since=since,
                                                   until=until)
        return _out(args, export)
    if args.csv is None:
        raise InvalidArgument("--csv OUT is required (or --writes for the record of writes)")
    # a damaged database: every row that can be read, what was skipped said on stderr
    with readable_database(args.database, "export") as db:
        return _out(args, _samples(args, db, since, until))


def _samples(args: argparse.Namespace, db: str, since: float | None,
             until: float | None) -> Callable[[IO[str]], int]:
    """The export of the samples of ``db`` (the database, or what was read of a
    damaged one)."""
    channels = None if args.channel is None else parse_channels(args.channel, HUB_STRIDE,
                                                               "--channel")
    given = _given_maps(args.maps)
    if args.events and args.layout == "wide":
        raise InvalidArgument("--events is for the long layout (an event is no sample)")
    wanted = _quantities(args.quantity, map_point_names(db, given)
                         if args.quantity is not None else [])
    device = device_name(db, args.device) if args.device is not None else None
    return partial(export_csv, db, device=device, since=since, until=until,
                   channels=channels, quantities=wanted, events=args.events,
                   layout=args.layout, maps=given)


def _out(args: argparse.Namespace, export: Callable[[IO[str]], int]) -> int:
    if args.csv == "-":
        export(sys.stdout)
        return 0
    out = args.csv
    if os.path.isdir(out):
        raise InvalidArgument(f"--csv {out} is a directory; give a file name")
    if os.path.exists(out):
        if os.path.samefile(out, args.database):
            raise InvalidArgument(f"--csv {out} is the database being exported: refusing to "
                                  "write onto it")
        if os.path.isfile(out) and os.path.getsize(out) and not _is_pymb_csv(out) \
                and not args.force:
            raise InvalidArgument(f"{out} exists and is not a CSV written by pymb: refusing "
                                  "to overwrite it (--force to do it anyway)")
    if os.path.exists(out) and not os.path.isfile(out):
        # A FIFO, a device: write to it directly.
        try:
            with open(out, "w", encoding="utf-8", newline="") as f:
                rows = export(f)
        except OSError as e:
            raise InvalidArgument(f"cannot write {out}: {e.strerror}") from None
    else:
        rows = _export_atomically(out, export)
    print(f"exported {rows:,} rows to {out}", file=sys.stderr)
    return 0


def _export_atomically(out: str, export: Callable[[IO[str]], int]) -> int:
    """Write a temporary file beside ``out``, rename it over ``out`` when done."""
    def terminated(signum: int, _frame: object) -> None:
        raise SystemExit(128 + signum)  # as a kill would, but the temporary file goes

    def write(fd: int, _tmp: str) -> int:
        with os.fdopen(fd, "w", encoding="utf-8", newline="") as f:
            return export(f)

    old = {s: signal.signal(s, terminated) for s in (signal.SIGTERM, signal.SIGHUP)}
    try:
        return write_beside(out, ".pymb-export-", ".csv.tmp", write, keep_mode=True)
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)
