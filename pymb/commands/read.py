"""``pymb read DEVICE``: one reading, as a table with units or JSON: a
CoolPro's or a hub's read as a map device (:func:`reader`) and shown as
their views always showed it, any other device through its map
(:func:`read_map`)."""

from __future__ import annotations

import argparse
import functools
import time
from collections.abc import Callable
from typing import Any

from pymb.client import Client
from pymb.commands._common import (
    add_connection_args,
    add_device_arg,
    add_map_arg,
    alias_spec,
    device_from_args,
    interruptible,
    make_client,
    print_json,
    render,
    to_json,
)
from pymb.commands.maptext import map_json, printable, render_map
from pymb.commands.sunspeccli import is_sunspec, sunspec_target
from pymb.devices import CoolProIdentity
from pymb.devices.deviceconfig import DeviceConfig
from pymb.devices.identify import WANTED_NAMES, Identity, client_asker, identify, mismatch
from pymb.devices.mapdevice import MapDevice
from pymb.devices.mapreading import MapReading
from pymb.devices.mapspec import (
    TYPED_VIEWS,
    MapTarget,
    map_types,
    match_map,
    parse_map_device,
    unknown_device,
)
from pymb.devices.readings import identity_view
from pymb.errors import DeviceException, InvalidArgument, ProtocolError
from pymb.maps.model import did_you_mean

#: the group a map's device says what it is with, read on request (``--identity``)
IDENTITY = "identity"


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
           channels: list[int] | None = None) -> Callable[[], MapReading]:
    """A function that returns one reading of ``dev`` (of a hub, only these
    ``blocks`` and ``channels`` if given) as a map reading; it raises
    :class:`~pymb.ProtocolError` saying what answered when the device
    supplied no value at all, and names what answered a device exception."""
    assert dev.address is not None
    address = dev.address
    count = int(dev.map.options.get("channels", 0))
    read: Callable[[], MapReading]
    if blocks is None and channels is None:
        mapdev, read_group = dev.open(client)
        read = functools.partial(read_group, dev.groups[0])
    else:  # a hub's few blocks or channels (pymb watch --block, --show)
        hub = dev.sweep_reader(client)
        mapdev, read = hub.device, functools.partial(hub.blocks, blocks or [], channels)

    def one() -> MapReading:
        try:
            data = read()
        except DeviceException as e:
            why = what_answers(client, address, dev.type, count)
            if "answers like" in why and "not" in why:
                raise type(e)(f"{why}; {e}", code=e.code) from None
            raise
        # The blocks asked for: when every one of them is missing, the device
        # supplied no value at all (a whole sweep, or watch's few blocks).
        if data.unsupported and set(blocks or data.values) <= set(data.unsupported):
            mapdev.planner.forget()  # the next read asks again
            why = what_answers(client, address, dev.type, count)
            raise ProtocolError(f"no value from {dev.type}:{address} on {client.port}: {why}",
                                reason="no value")
        return data

    return one


def identity_of(dev: DeviceConfig, client: Client
                ) -> CoolProIdentity | MapReading | Identity | None:
    """What the device says it is: its map's ``identity`` group read on
    request (``poll = "request"``) as its view shows it (a CoolPro's serial
    number, firmware and manufacture date); for a map without one (an
    identity group it polls, as the Carlo Gavazzi meters', included), what
    identification finds (a hub's channels and firmware:
    :mod:`pymb.devices.identify`)."""
    assert dev.address is not None
    if IDENTITY in dev.map.groups and dev.map.polled(IDENTITY) == "request":
        return identity_view(dev.open(client)[1](IDENTITY))
    return identify(client_asker(client), dev.address)


def identity_text(ident: CoolProIdentity | MapReading | Identity | None) -> str:
    """The identity as lines of text."""
    if ident is None:
        return "Identity         nothing answers to the identification"
    if isinstance(ident, Identity):
        return f"{'Identity':<16} {ident.describe()}"
    return render(ident)


def identity_json(ident: CoolProIdentity | MapReading | Identity | None) -> Any:
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

    def io() -> tuple[Any, float, CoolProIdentity | MapReading | Identity | None]:
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


def target_from_args(args: argparse.Namespace) -> MapTarget | None:
    """The map device the positional DEVICE names (with ``--address``), or
    None for ``coolpro``/``hub`` without ``--group`` (shown as their views);
    an unknown TYPE is a one-line error that names the map types known."""
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
        if kind not in TYPED_VIEWS:
            raise unknown_device(args.device, list(known))
        if getattr(args, "group", None) is None:
            return None
        # One group of a typed view's map (its request groups too: the
        # CoolPro's identity): read and shown as any map device's.
        target = parse_map_device(alias_spec(args.device, args), map_types(views=True))
        assert target is not None
        _check_group(args, target)
        return target
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


def read_points(dev: MapDevice, target: MapTarget, client: Client,
                group: str | None) -> dict[str, Any]:
    """One reading of a map device's points (of ``group``: every readable
    one if None), as :meth:`MapDevice.read` gives it; a reading in which the
    device refused every point (no value at all: another device, or none
    that knows these registers, at that address) raises
    :class:`~pymb.ProtocolError` saying what answered there, as for a
    CoolPro or a hub."""
    values = dev.read(group=group)
    if values and all(_refused(dev.states.get(name)) for name in values):
        dev.planner.forget()  # the next read asks again
        why = what_answers(client, target.address, target.map.id, 0)
        raise ProtocolError(f"no value from {target.spec} on {client.port}: {why}",
                            reason="no value")
    return values


def what_answers(client: Client, address: int, wanted: str, channels: int) -> str:
    """Why a read of ``wanted`` at ``address`` got no value, in one phrase:
    what answers there, by the ``[[identify]]`` rules of the shipped maps as
    ``pymb scan`` names it (an energy meter is not taken for a CoolPro whose
    identity registers it happens to have), else as :func:`mismatch` says."""
    ask = client_asker(client)
    found = identify(ask, address)
    if found is not None:
        matched = match_map(ask, address, map_types())
        if matched is not None and matched[0] != wanted:
            name = WANTED_NAMES.get(wanted, wanted)
            return (f"address {address} answers like {matched[0]} ({matched[1]}), not {name}: "
                    f"read it as {matched[0]}:{address}")
    return mismatch(found, wanted, address, channels)


def _refused(state: Any) -> bool:
    """A point's (a block's: every channel's) state says the device refused it."""
    if isinstance(state, (list, tuple)):
        return bool(state) and all(s == "unsupported" for s in state)
    return bool(state == "unsupported")


def map_device(args: argparse.Namespace, target: MapTarget, client: Client) -> MapDevice:
    """The :class:`MapDevice` of ``target`` on ``client`` (``pymb read``, ``pymb watch``)."""
    return MapDevice(client, target.map, target.address, baudrate=args.baud)


def _identity(dev: MapDevice) -> dict[str, Any]:
    info = dev.map.device
    points = [r.point for r in dev.map.identify]
    values = dev.read(*dict.fromkeys(points)) if points else {}
    return {"device": dev.map.id, "manufacturer": info.manufacturer, "model": info.model,
            "points": values}


def _identity_text(ident: dict[str, Any]) -> str:
    what = " ".join(x for x in (ident["manufacturer"], ident["model"]) if x) or ident["device"]
    extra = ", ".join(f"{k} {printable(v)}" for k, v in ident["points"].items())
    return f"{'Identity':<16} {what}" + (f" ({extra})" if extra else "")


def read_map(args: argparse.Namespace, target: MapTarget) -> int:
    """``pymb read`` of a map device: one reading, printed."""
    client = make_client(args)
    dev = map_device(args, target, client)
    group = getattr(args, "group", None)

    def io() -> tuple[dict[str, Any], dict[str, Any], float, dict[str, Any] | None]:
        with client:
            t0 = time.monotonic()
            values = read_points(dev, target, client, group)
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
