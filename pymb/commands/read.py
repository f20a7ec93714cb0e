"""``pymb read coolpro|hub``: one reading, as a table with units or JSON."""

from __future__ import annotations

import argparse
import time
from typing import Any

from pymb.client import Client
from pymb.commands._common import add_connection_args, make_client, print_json, render, to_json
from pymb.devices import HUB, CoolPro, SensorHub
from pymb.devices.maps import COOLPRO


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Arguments of ``pymb read`` (also used by ``pymb watch``)."""
    p.add_argument("device", choices=["coolpro", "hub"], help="which device")
    add_connection_args(p)
    p.add_argument("--address", type=int,
                   help=f"device address (coolpro {COOLPRO.default_address}, hub "
                        f"{HUB.default_address} by default)")
    p.add_argument("--channels", type=int, default=HUB.channels,
                   help="hub channels (50 for firmware V1.07 and below)")
    p.add_argument("--humidity-unit", type=float, default=0.1, choices=[1, 0.1],
                   help="hub humidity unit in %% (default 0.1)")
    p.add_argument("--identity", action="store_true",
                   help="coolpro: also read serial number, firmware and manufacture date")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")


def reader(args: argparse.Namespace, client: Client) -> Any:
    """A function that returns one reading of the device the arguments name."""
    if args.device == "coolpro":
        return CoolPro(client, args.address or COOLPRO.default_address).read_telemetry
    hub = SensorHub(client, args.address or HUB.default_address, args.channels,
                    args.humidity_unit)
    return hub.read_all


def run(args: argparse.Namespace) -> int:
    """One reading, printed."""
    client = make_client(args)
    read = reader(args, client)  # validates the address before any I/O
    with client:
        t0 = time.monotonic()
        data = read()
        elapsed = time.monotonic() - t0
        identity = None
        if args.identity and args.device == "coolpro":
            identity = CoolPro(client, args.address or COOLPRO.default_address).read_identity()
    if args.json:
        out = {"device": args.device, "port": client.port, "address": args.address,
               "time_utc": time.time(), "read_s": elapsed, **to_json(data)}
        if identity is not None:
            out["identity"] = to_json(identity)
        print_json(out)
    else:
        print(render(data))
        if identity is not None:
            print(render(identity))
    return 0
