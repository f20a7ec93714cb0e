"""``pymb watch DEVICE``: ``pymb read``, refreshed live, with the rate.

On a terminal each frame is drawn to fit it (80x24 included): the status
line first, always on screen, then a compact view: a CoolPro's telemetry,
or for a hub the chosen blocks (``--block``, default temperature and
humidity) with ten channels to a row, as many rows as fit (``--show``
chooses the channels), or a map device's points (:func:`watch_map`, cut to
fit by :func:`screen`). ``--json`` prints one JSON object per line per read
attempt instead. Elsewhere (a pipe, a file) each frame is printed after the
last.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import queue
import shutil
import sys
import threading
import time
from collections.abc import Callable
from typing import Any, TypeVar

from pymb.commands import read as read_cmd
from pymb.commands._common import (
    device_from_args,
    interruptible,
    make_client,
    parse_channels,
    render,
    to_json,
)
from pymb.commands.maptext import indexed, map_json, render_map
from pymb.devices.mapreading import MapReading, group_points
from pymb.devices.mapspec import MapTarget
from pymb.devices.polls import Health
from pymb.devices.spec import closest
from pymb.errors import InvalidArgument, ModbusConnectionError, ModbusError

_STATE_WORDS = {"offline": "off", "no_sensor": "-", "unsupported": "n/a", "not_read": ""}
_CELL = 6  # characters per value: "-327.6" at most, a space before

T = TypeVar("T")


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Arguments of ``pymb watch``: those of ``pymb read`` plus the pace and the view."""
    read_cmd.add_arguments(p)
    p.add_argument("--interval", type=float, default=0.0,
                   help="seconds between reads (default 0: as fast as the line allows)")
    p.add_argument("--count", type=int, default=0,
                   help="stop after N read attempts, failed ones included (default: never)")
    p.add_argument("--block", action="append", default=[], metavar="NAME",
                   help="hub: the block(s) to show and read, e.g. temperature_c or "
                        "temperature_c,pressure_kpa (default temperature_c,humidity_pct; "
                        "'all' for every block)")
    p.add_argument("--show", metavar="CHANNELS",
                   help="hub: the channels to show and read, e.g. 1-20 or 1-10,40 "
                        "(default: all)")


def parse_blocks(names: list[str], known: list[str]) -> list[str]:
    """Names of the ``known`` blocks (each with or without its unit's
    suffix), 'all', or by default the first two (a hub's temperature and
    humidity)."""
    short = {n.rsplit("_", 1)[0]: n for n in known}
    out: list[str] = []
    for name in (n.strip() for arg in names for n in arg.split(",") if n.strip()):
        if name == "all":
            return list(known)
        full = name if name in known else short.get(name)
        if full is None:
            raise InvalidArgument(f"unknown --block {name!r}{closest(name, known)}")
        if full not in out:
            out.append(full)
    return out or list(known[:2])


def _value(v: Any, state: str) -> str:
    if state == "value":
        return f"{v:.1f}" if v != int(v) or abs(v) < 1000 else f"{v:.0f}"
    return _STATE_WORDS.get(state, "?")


def hub_view(data: MapReading, blocks: list[str], shown: list[int], width: int,
             height: int) -> list[str]:
    """The hub's chosen blocks and channels in at most ``height`` lines of at
    most ``width`` characters: ten (or five, or twenty) channels to a row."""
    per_row = (width - 5) // _CELL
    per_row = next((n for n in (20, 10, 5) if n <= per_row), max(1, per_row))
    lines: list[str] = []
    for name in blocks:
        values, states = data.values[name], data.states[name]
        assert isinstance(values, list)
        vals = [(ch, _value(values[ch - 1], states[ch - 1])) for ch in shown]
        lines.append(f"{name} [{data.map.points[name].unit}]"[:width])
        for i in range(0, len(vals), per_row):
            row = vals[i:i + per_row]
            lines.append((f"{row[0][0]:>3}: " + "".join(v.rjust(_CELL) for _, v in row))[:width])
    if len(lines) > height:
        hidden = len(lines) - height + 1
        note = f"… {hidden} more line(s): choose with --block or --show"[:width]
        lines = [*lines[:height - 1], note]
    return lines


def _check_pace(args: argparse.Namespace) -> None:
    """Refuse a negative ``--count`` and an ``--interval`` that is no number of seconds."""
    if args.count < 0:
        raise InvalidArgument(f"--count must be 0 (no limit) or more, got {args.count}")
    if not (math.isfinite(args.interval) and args.interval >= 0):
        raise InvalidArgument(f"--interval must be 0 or more seconds, got {args.interval:g}")


def poll(args: argparse.Namespace, stop: threading.Event, health: Health,
         read: Callable[[], T], show: Callable[[T | None, str | None], None]) -> None:
    """Read until ``stop`` or ``--count`` attempts, ``--interval`` apart; each
    attempt is shown: ``show(reading, None)`` or ``show(None, error)``. A
    fault that backs the device off (``health``) says when the next try comes
    and waits for it; a lost connection ends the loop (it raises)."""
    attempts = 0
    while not stop.is_set() and (args.count <= 0 or attempts < args.count):
        start = time.monotonic()
        attempts += 1
        try:
            data = read()
        except ModbusConnectionError:
            raise
        except ModbusError as e:
            no_value = getattr(e, "reason", "") == "no value"
            next_try = health.failed(time.monotonic(), at_once=no_value)
            if next_try and not 0 < args.count <= attempts:  # a next try to wait for
                show(None, f"{e}{next_try}")
                stop.wait(health.backoff)
                continue
            show(None, str(e))
        else:
            health.answered()
            show(data, None)
        if args.interval > 0:
            stop.wait(max(0.0, args.interval - (time.monotonic() - start)))


def run(args: argparse.Namespace) -> int:
    """Read, redraw, repeat until Ctrl-C (or --count attempts)."""
    target = read_cmd.target_from_args(args)  # a device a map describes
    if target is not None:
        return watch_map(args, target)
    dev = device_from_args(args)
    _check_pace(args)
    # An indexed array (a hub's sweep: blocks of as many channels) is shown
    # block by block, the blocks and channels chosen read alone.
    names = group_points(dev.map, dev.groups[0] if dev.groups else None)
    is_table = indexed(dev.map, names)
    channels = dev.map.points[names[0]].channels if is_table else 0
    if not is_table and (args.block or args.show):
        raise InvalidArgument("--block and --show are for a hub")
    blocks = parse_blocks(args.block, names) if is_table else []
    shown = parse_channels(args.show, channels) if is_table and args.show else (
        list(range(1, channels + 1)))
    full = is_table and len(blocks) == len(names) and len(shown) == channels
    client = make_client(args)
    read = read_cmd.reader(dev, client, blocks=None if full or not is_table else blocks,
                           channels=None if full or not is_table else shown)
    frames: queue.Queue[tuple[str, Any]] = queue.Queue(maxsize=4)
    stop = threading.Event()

    def io() -> None:
        try:
            with client:
                if args.identity:
                    frames.put(("identity", read_cmd.identity_of(dev, client)))
                # as ``pymb log``'s: a device that supplied no value is backed off
                # at once, any other fault after a run of them
                health = Health.of_map(dev.name, dev.offline_after, dev.offline_retry,
                                       dev.map.timing.backoff)
                poll(args, stop, health, read, lambda data, error: frames.put(
                    ("data", data) if error is None else ("error", error)))
        except BaseException as e:  # handed to the main thread
            frames.put(("fatal", e))
        frames.put(("end", None))

    threading.Thread(target=io, name="pymb-watch", daemon=True).start()
    tty = sys.stdout.isatty() and not args.json
    done = faults = attempts = 0
    identity = ""
    identity_doc: Any = None
    t0 = time.monotonic()
    last_draw = 0.0
    last: tuple[str, Any] | None = None  # the newest reading not drawn yet
    if tty:
        sys.stdout.write("\x1b[H\x1b[2J")

    def draw(kind: str, item: Any) -> None:
        elapsed = time.monotonic() - t0
        rate = done / elapsed if elapsed > 0 else 0.0
        # The status line: the words that matter first, the port last (cut first).
        head = (f"{dev.spec}  {done} reads {rate:.1f}/s  faults {faults}/{attempts}  "
                f"on {client.port}")
        width, height = terminal_size() if tty else (10**6, 10**6)
        body: list[str] = []
        if identity:
            body += identity.splitlines()
        if kind == "error":
            body.append(f"error: {item}")
        elif is_table:
            body += hub_view(item, blocks, shown, width, height - 1 - len(body))
        else:
            body += render(item).splitlines()
        if tty:
            lines = [ln[:width - 1] if len(ln) >= width else ln for ln in [head, *body]]
            # Home, draw, clear the rest; no newline after the last line, so
            # nothing scrolls and the status line stays on screen.
            sys.stdout.write("\x1b[H" + "\x1b[K\n".join(lines[:height]) + "\x1b[K\x1b[J")
        else:
            sys.stdout.write(head + "\n" + "\n".join(body) + "\n\n")
        sys.stdout.flush()

    try:
        while True:
            try:
                kind, item = frames.get(timeout=0.1)
            except queue.Empty:
                if last is not None and time.monotonic() - last_draw >= 0.1:
                    draw(*last)
                    last, last_draw = None, time.monotonic()
                continue
            if kind == "end":
                break
            if kind == "fatal":
                raise item
            if kind == "identity":
                identity, identity_doc = read_cmd.identity_text(item), read_cmd.identity_json(item)
                continue
            attempts += 1
            if kind == "data":
                done += 1
            else:
                faults += 1
            if args.json:
                out: dict[str, Any] = {"time_utc": time.time(), "device": dev.type,
                                       "address": dev.address, "port": client.port,
                                       "attempt": attempts}
                if identity:
                    out["identity"] = identity_doc
                if kind == "data":
                    out.update(to_json(item))
                else:
                    out["error"] = str(item)
                sys.stdout.write(json.dumps(out, allow_nan=False) + "\n")
                sys.stdout.flush()
                continue
            last = (kind, item)
            # A terminal is redrawn at most ten times a second; a pipe gets every frame.
            if not tty or time.monotonic() - last_draw >= 0.1:
                draw(*last)
                last, last_draw = None, time.monotonic()
        if last is not None:
            draw(*last)
    finally:
        stop.set()
        if tty:
            sys.stdout.write("\n")
            sys.stdout.flush()
    return 0 if done or attempts == 0 else 3


def fit(lines: list[str], width: int, height: int) -> list[str]:
    """A map device's lines in at most ``height`` lines of fewer than
    ``width`` characters: those that do not fit give way to one that says
    how many more there are (as the hub view does)."""
    if height < 1:
        return []
    if len(lines) > height:
        hidden = len(lines) - height + 1
        lines = [*lines[:height - 1], f"… {hidden} more: use --group"]
    return [ln[:width - 1] if len(ln) >= width else ln for ln in lines]


def screen(head: str, body: list[str], width: int, height: int) -> str:
    """A frame for a terminal: home, the status line (always on screen) and
    what of ``body`` fits below it, the rest of the screen cleared; no newline
    after the last line, so nothing scrolls."""
    lines = fit([head], width, 1) + fit(body, width, height - 1)
    return "\x1b[H" + "\x1b[K\n".join(lines) + "\x1b[K\x1b[J"


def terminal_size() -> tuple[int, int]:
    """(columns, lines) of the terminal on stdout (80x24 when it says none,
    or 0x0 as a board's serial console does)."""
    try:
        size = os.get_terminal_size(sys.stdout.fileno())
        if size.columns > 0 and size.lines > 0:
            return size.columns, size.lines
        raise OSError("no size")
    except (OSError, ValueError):
        fallback = shutil.get_terminal_size((80, 24))
        return fallback.columns, fallback.lines


def watch_map(args: argparse.Namespace, target: MapTarget) -> int:
    """``pymb watch`` of a map device: read, print, repeat until Ctrl-C or
    ``--count`` attempts; a terminal is redrawn in place, a pipe gets every
    reading (JSON lines with ``--json``)."""
    _check_pace(args)
    if args.block or args.show:
        if getattr(args, "group", None) is not None:
            raise InvalidArgument("--block and --show choose a hub's blocks and channels; "
                                  "--group shows every point of its group")
        raise InvalidArgument("--block and --show are for a hub")
    client = make_client(args)
    dev = read_cmd.map_device(args, target, client)
    group = getattr(args, "group", None)
    tty = sys.stdout.isatty() and not args.json
    stop = threading.Event()
    counts = {"done": 0, "faults": 0, "attempts": 0}
    t0 = time.monotonic()

    def show(values: dict[str, Any] | None, error: str | None) -> None:
        counts["attempts"] += 1
        counts["done" if error is None else "faults"] += 1
        elapsed = time.monotonic() - t0
        if args.json:
            out: dict[str, Any] = {"time_utc": time.time(), "device": target.map.id,
                                   "address": target.address, "port": client.port,
                                   "attempt": counts["attempts"]}
            if values is not None:
                out.update(map_json(values, dev.states))
            else:
                out["error"] = str(error)
            sys.stdout.write(json.dumps(out, allow_nan=False) + "\n")
        else:
            rate = counts["done"] / elapsed if elapsed > 0 else 0.0
            head = (f"{target.spec}  {counts['done']} reads {rate:.1f}/s  faults "
                    f"{counts['faults']}/{counts['attempts']}  on {client.port}")
            body = (render_map(target.map, values, dev.states) if values is not None
                    else f"error: {error}")
            if tty:
                sys.stdout.write(screen(head, body.splitlines(), *terminal_size()))
            else:
                sys.stdout.write(head + "\n" + body + "\n\n")
        sys.stdout.flush()

    def io() -> None:
        # as for a CoolPro or a hub: a reading with no value at all waits at
        # once (0.5 s, doubling up to 30 s), any other fault after ten in a row
        with client:
            poll(args, stop, Health.of_map(target.spec, 10, None, backoff=True),
                 lambda: read_cmd.read_points(dev, target, client, group), show)

    try:
        interruptible(io)
    finally:
        stop.set()
    return 0 if counts["done"] or counts["attempts"] == 0 else 3
