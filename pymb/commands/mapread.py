"""``pymb read`` and ``pymb watch`` of a device a map describes
(``TYPE`` a map's id: a shipped map's, or a ``--map FILE``'s)."""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import sys
import threading
import time
from typing import Any

from pymb.client import Client
from pymb.commands._common import interruptible, make_client, print_json
from pymb.commands.mapcli import map_json, render_map
from pymb.commands.sunspeccli import is_sunspec, sunspec_target
from pymb.devices.mapdevice import MapDevice
from pymb.devices.mapspec import (
    FACADES,
    MapTarget,
    map_types,
    parse_map_device,
    unknown_device,
)
from pymb.errors import InvalidArgument, ModbusConnectionError, ModbusError
from pymb.maps.model import did_you_mean

__all__ = ["fit", "read_map", "screen", "target_from_args", "terminal_size", "watch_map"]


def target_from_args(args: argparse.Namespace) -> MapTarget | None:
    """The map device the positional DEVICE names (with ``--address``), or
    None for ``coolpro``/``hub``; an unknown TYPE is a one-line error that
    names the map types known."""
    if is_sunspec(args.device):
        if getattr(args, "address", None) is not None:
            raise InvalidArgument("give a SunSpec device's unit id as sunspec:ADDRESS")
        found = sunspec_target(args, args.device)[0]
        _check_group(args, found)
        return found
    known = map_types(getattr(args, "maps", None) or [])
    target = parse_map_device(args.device, known)
    kind = args.device.split(",")[0].partition(":")[0].strip().lower()
    if target is None:
        if kind not in FACADES:
            raise unknown_device(args.device, list(known))
        if getattr(args, "group", None):
            raise InvalidArgument("--group is for a device read through a map")
        return None
    for flag in ("channels", "humidity_unit"):
        if getattr(args, flag, None) is not None:
            raise InvalidArgument(f"--{flag.replace('_', '-')} is for a hub; a map's options "
                                  f"are given as {kind}:ADDRESS,name=value")
    if getattr(args, "address", None) is not None:
        if ":" in args.device.split(",")[0] and args.address != target.address:
            raise InvalidArgument(f"{args.device!r} gives address {target.address} and "
                                  f"--address {args.address}: give it once")
        spec = args.device.split(",")
        spec[0] = f"{kind}:{args.address}"
        target = parse_map_device(",".join(spec), known)
        assert target is not None
    _check_group(args, target)
    return target


def _check_group(args: argparse.Namespace, target: MapTarget) -> None:
    group = getattr(args, "group", None)
    if group is not None and group not in target.map.groups:
        raise InvalidArgument(f"{target.map.id} has no group {group!r}"
                              f"{did_you_mean(group, list(target.map.groups))}")


def _device(args: argparse.Namespace, target: MapTarget, client: Client) -> MapDevice:
    return MapDevice(client, target.map, target.address, baudrate=args.baud)


def _identity(dev: MapDevice) -> dict[str, Any]:
    info = dev.map.device
    points = [r.point for r in dev.map.identify]
    values = dev.read(*dict.fromkeys(points)) if points else {}
    return {"device": dev.map.id, "manufacturer": info.manufacturer, "model": info.model,
            "points": values}


def _identity_text(ident: dict[str, Any]) -> str:
    what = " ".join(x for x in (ident["manufacturer"], ident["model"]) if x) or ident["device"]
    extra = ", ".join(f"{k} {v}" for k, v in ident["points"].items())
    return f"{'Identity':<16} {what}" + (f" ({extra})" if extra else "")


def read_map(args: argparse.Namespace, target: MapTarget) -> int:
    """``pymb read`` of a map device: one reading, printed."""
    client = make_client(args)
    dev = _device(args, target, client)
    group = getattr(args, "group", None)

    def io() -> tuple[dict[str, Any], dict[str, Any], float, dict[str, Any] | None]:
        with client:
            t0 = time.monotonic()
            values = dev.read(group=group)
            states = dev.states
            elapsed = time.monotonic() - t0
            ident = _identity(dev) if args.identity else None
        return values, states, elapsed, ident

    values, states, elapsed, ident = interruptible(io)
    if args.json:
        out = {"device": target.map.id, "port": client.port, "address": target.address,
               "time_utc": time.time(), "read_s": elapsed, **map_json(values, states)}
        if ident is not None:
            out["identity"] = ident
        print_json(out)
    else:
        print(render_map(target.map, values, states))
        if ident is not None:
            print(_identity_text(ident))
    return 0


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
    """(columns, lines) of the terminal on stdout (80x24 when it says none)."""
    try:
        size = os.get_terminal_size(sys.stdout.fileno())
        return size.columns, size.lines
    except (OSError, ValueError):
        fallback = shutil.get_terminal_size((80, 24))
        return fallback.columns, fallback.lines


def watch_map(args: argparse.Namespace, target: MapTarget) -> int:
    """``pymb watch`` of a map device: read, print, repeat until Ctrl-C or
    ``--count`` attempts; a terminal is redrawn in place, a pipe gets every
    reading (JSON lines with ``--json``)."""
    if args.count < 0:
        raise InvalidArgument(f"--count must be 0 (no limit) or more, got {args.count}")
    if not (math.isfinite(args.interval) and args.interval >= 0):
        raise InvalidArgument(f"--interval must be 0 or more seconds, got {args.interval:g}")
    if args.block or args.show:
        raise InvalidArgument("--block and --show are for a hub")
    client = make_client(args)
    dev = _device(args, target, client)
    group = getattr(args, "group", None)
    tty = sys.stdout.isatty() and not args.json
    stop = threading.Event()
    counts = {"done": 0, "faults": 0, "attempts": 0}
    t0 = time.monotonic()

    def show(values: dict[str, Any] | None, error: ModbusError | None) -> None:
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
        with client:
            while not stop.is_set() and (args.count <= 0 or counts["attempts"] < args.count):
                start = time.monotonic()
                counts["attempts"] += 1
                try:
                    values = dev.read(group=group)
                except ModbusConnectionError:
                    raise
                except ModbusError as e:
                    counts["faults"] += 1
                    show(None, e)
                else:
                    counts["done"] += 1
                    show(values, None)
                if args.interval > 0:
                    stop.wait(max(0.0, args.interval - (time.monotonic() - start)))

    try:
        interruptible(io)
    finally:
        stop.set()
    return 0 if counts["done"] or counts["attempts"] == 0 else 3
