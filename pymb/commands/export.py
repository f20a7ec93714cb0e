"""``pymb export FILE.sqlite --csv OUT``: get logged data back out."""

from __future__ import annotations

import argparse
import sys
from datetime import UTC, datetime

from pymb.errors import InvalidArgument
from pymb.store import export_csv


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Arguments of ``pymb export``."""
    p.add_argument("database", help="a database written by pymb log / pymb demo")
    p.add_argument("--csv", required=True, metavar="OUT",
                   help="write long-format CSV here ('-' for stdout)")
    p.add_argument("--device", help="only this device (its name, e.g. hub-1)")
    p.add_argument("--since", help="only data from this UTC time on (ISO 8601)")
    p.add_argument("--events", action="store_true", help="include the events (faults etc.)")


def run(args: argparse.Namespace) -> int:
    """Export; prints how many rows went out."""
    since = None
    if args.since:
        try:
            t = datetime.fromisoformat(args.since.replace("Z", "+00:00"))
        except ValueError:
            raise InvalidArgument(f"--since needs an ISO 8601 time, got {args.since!r}") from None
        if t.tzinfo is None:
            t = t.replace(tzinfo=UTC)
        since = t.timestamp()
    if args.csv == "-":
        rows = export_csv(args.database, sys.stdout, device=args.device, since=since,
                          events=args.events)
    else:
        try:
            with open(args.csv, "w", encoding="utf-8", newline="") as f:
                rows = export_csv(args.database, f, device=args.device, since=since,
                                  events=args.events)
        except OSError as e:
            raise InvalidArgument(f"cannot write {args.csv}: {e.strerror}") from None
        print(f"exported {rows:,} rows to {args.csv}", file=sys.stderr)
    return 0
