"""``pymb read DEVICE``: one reading, as a table with units or JSON."""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from typing import Any

from pymb.client import Client
from pymb.commands._common import (
    add_connection_args,
    add_device_arg,
    device_from_args,
    interruptible,
    make_client,
    print_json,
    render,
    to_json,
)
from pymb.commands.mapcli import add_map_arg
from pymb.commands.mapread import read_map, target_from_args
from pymb.devices import HUB, CoolPro, CoolProIdentity, HubReading, SensorHub
from pymb.devices.hub import ALL_BLOCKS
from pymb.devices.identify import Identity, client_asker, identify, mismatch
from pymb.devices.spec import DeviceConfig
from pymb.errors import DeviceException, ProtocolError


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Arguments of ``pymb read`` (also used by ``pymb watch``)."""
    add_device_arg(p)
    add_connection_args(p)
    p.add_argument("--identity", action="store_true",
                   help="also say what the device is: a CoolPro's serial number, firmware "
                        "and manufacture date; a hub's channels and firmware")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    add_map_arg(p, group=True)


def reader(dev: DeviceConfig, client: Client, *, blocks: list[str] | None = None,
           channels: list[int] | None = None) -> Callable[[], Any]:
    """A function that returns one reading of ``dev``; it raises
    :class:`~pymb.ProtocolError` saying what answered when the device
    supplied no value at all, and names what answered a device exception."""
    assert dev.address is not None
    address = dev.address
    # The blocks asked for: when every one of them is missing, the device
    # supplied no value at all (a whole sweep, or watch's few blocks).
    wanted = ALL_BLOCKS if blocks is None else sum(1 << HUB.block(b).index for b in blocks)
    if dev.type == "coolpro":
        read: Callable[[], Any] = CoolPro(client, address).read_telemetry
        hub = None
    else:
        hub = SensorHub(client, address, dev.channels, dev.humidity_unit)
        read = hub.read_all if blocks is None and channels is None else (
            lambda: hub.read(blocks, channels))  # type: ignore[union-attr]

    def one() -> Any:
        try:
            data = read()
        except DeviceException as e:
            why = mismatch(identify(client_asker(client), address), dev.type, address,
                           dev.channels)
            if "answers like" in why and "not" in why:
                raise type(e)(f"{why}; {e}", code=e.code) from None
            raise
        if hub is not None and isinstance(data, HubReading) and \
                data.unsupported_mask & wanted == wanted:
            hub.forget_firmware()  # the next read asks again
            why = mismatch(identify(client_asker(client), address), "hub", address,
                           dev.channels)
            raise ProtocolError(f"no value from hub:{address} on {client.port}: {why}",
                                reason="no value")
        return data

    return one


def identity_of(dev: DeviceConfig, client: Client) -> CoolProIdentity | Identity | None:
    """What the device says it is: a CoolPro's identity registers; for a hub
    its channels and firmware (see :mod:`pymb.devices.identify`)."""
    assert dev.address is not None
    if dev.type == "coolpro":
        return CoolPro(client, dev.address).read_identity()
    return identify(client_asker(client), dev.address)


def identity_text(ident: CoolProIdentity | Identity | None) -> str:
    """The identity as lines of text."""
    if ident is None:
        return "Identity         nothing answers to the identification"
    if isinstance(ident, Identity):
        return f"{'Identity':<16} {ident.describe()}"
    return render(ident)


def identity_json(ident: CoolProIdentity | Identity | None) -> Any:
    """The identity as JSON."""
    if isinstance(ident, Identity):
        return {"device": ident.device, "detail": ident.detail, "channels": ident.channels,
                "blocks": list(ident.blocks)}
    return None if ident is None else to_json(ident)


def run(args: argparse.Namespace) -> int:
    """One reading, printed."""
    target = target_from_args(args)  # a device a map describes
    if target is not None:
        return read_map(args, target)
    dev = device_from_args(args)  # checked before any I/O
    client = make_client(args)
    read = reader(dev, client)

    def io() -> tuple[Any, float, CoolProIdentity | Identity | None]:
        with client:
            t0 = time.monotonic()
            data = read()
            elapsed = time.monotonic() - t0
            ident = identity_of(dev, client) if args.identity else None
        return data, elapsed, ident

    data, elapsed, identity = interruptible(io)
    if args.json:
        out = {"device": dev.type, "port": client.port, "address": dev.address,
               "time_utc": time.time(), "read_s": elapsed, **to_json(data)}
        if args.identity:
            out["identity"] = identity_json(identity)
        print_json(out)
    else:
        print(render(data))
        if args.identity:
            print(identity_text(identity))
    return 0
