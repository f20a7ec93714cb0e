"""``pymb salvage DAMAGED NEW``: every row that can still be read from a
damaged pymb database, copied into a new database (see
:mod:`pymb.store.salvage`). DAMAGED is only read; NEW must not exist."""

from __future__ import annotations

import argparse
import sys

from pymb.store.salvage import salvage

__all__ = ["add_arguments", "run"]


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Arguments of ``pymb salvage``."""
    p.add_argument("damaged", help="the damaged database (only read, never changed)")
    p.add_argument("new", help="the new database to write (must not exist)")


def run(args: argparse.Namespace) -> int:
    """Salvage; says what was copied and what was skipped (exit 0 once NEW is
    written, whatever could not be read)."""
    result = salvage(args.damaged, args.new)
    for line in result.lines():
        print(f"pymb salvage: {line}", file=sys.stderr)
    print(f"pymb salvage: wrote {args.new}" + (
        "; the rows above could not be read" if result.skipped else "; nothing was skipped"),
        file=sys.stderr)
    return 0
