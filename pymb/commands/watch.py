"""``pymb watch coolpro|hub``: ``pymb read``, refreshed live, with the rate."""

from __future__ import annotations

import argparse
import sys
import time

from pymb.commands import read as read_cmd
from pymb.commands._common import make_client, render
from pymb.errors import ModbusConnectionError, ModbusError


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Arguments of ``pymb watch``: those of ``pymb read`` plus the pace."""
    read_cmd.add_arguments(p)
    p.add_argument("--interval", type=float, default=0.0,
                   help="seconds between reads (default 0: as fast as the line allows)")
    p.add_argument("--count", type=int, default=0, help="stop after N reads (default: never)")


def run(args: argparse.Namespace) -> int:
    """Read, redraw, repeat until Ctrl-C (or --count)."""
    tty = sys.stdout.isatty()
    done = faults = 0
    t0 = time.monotonic()
    client = make_client(args)
    read = read_cmd.reader(args, client)  # validates the address before any I/O
    with client:
        while args.count <= 0 or done < args.count:
            start = time.monotonic()
            try:
                data = read()
                text = render(data)
                done += 1
            except ModbusConnectionError:
                raise
            except ModbusError as e:
                faults += 1
                text = f"error: {e}"
            elapsed = time.monotonic() - t0
            rate = done / elapsed if elapsed > 0 else 0.0
            head = (f"pymb watch {args.device} on {client.port}: {done} reads, {rate:.1f}/s, "
                    f"{faults} faults")
            if tty:
                sys.stdout.write("\x1b[H\x1b[2J" + head + "\n\n" + text + "\n")
            else:
                sys.stdout.write(head + "\n" + text + "\n\n")
            sys.stdout.flush()
            if args.interval > 0:
                time.sleep(max(0.0, args.interval - (time.monotonic() - start)))
    return 0
