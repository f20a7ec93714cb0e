"""What the subcommands share: connection arguments, ``--map FILE``, the
client they make, and the text and JSON renderings of a reading."""

from __future__ import annotations

import argparse
import json
import os
import stat
import sys
import threading
from collections.abc import Callable
from typing import Any, TypeVar

from pymb import maps
from pymb.client import (
    AsciiClient,
    Client,
    RtuClient,
    TlsConfig,
    UdpClient,
    client_for_address,
    parse_host_port,
    unresolved,
)
from pymb.client.address import is_mbaps
from pymb.commands.maptext import indexed, reading_text
from pymb.devices import CoolProIdentity
from pymb.devices.deviceconfig import DeviceConfig, KnownMaps, parse_device
from pymb.devices.mapreading import MapReading
from pymb.devices.mapspec import TYPED_VIEWS
from pymb.devices.readings import reading_dict
from pymb.devices.spec import split_spec
from pymb.errors import InvalidArgument, ModbusConnectionError
from pymb.wire import DEFAULT_BAUD, DEFAULT_PARITY, DEFAULT_TIMEOUT

__all__ = [
    "add_alias_args",
    "add_connection_args",
    "add_device_arg",
    "add_map_arg",
    "add_serial_args",
    "alias_spec",
    "device_from_args",
    "device_help",
    "interruptible",
    "make_client",
    "never_a_line",
    "parse_channels",
    "parse_numbers",
    "render",
    "serial_options",
    "to_json",
]

T = TypeVar("T")

def device_help() -> str:
    """The help of a DEVICE argument of a command that reads any device:
    the syntax, the types (the shipped maps' ids among them) and examples."""
    ids = [i for i in maps.builtin_ids() if i not in TYPED_VIEWS]
    return (f"the device: TYPE[:ADDRESS][,key=value...], TYPE coolpro, hub or a map's id "
            f"(shipped: {', '.join(ids)}; --map FILE adds one), e.g. coolpro:41, hub:250, "
            f"hub:7,channels=50,humidity_unit=1, {ids[0] if ids else 'my-meter'}:3")


def add_device_arg(p: argparse.ArgumentParser, *, hub_options: bool = True) -> None:
    """The positional DEVICE and its aliases (--address, --channels, --humidity-unit);
    without ``hub_options``, a CoolPro only (``pymb config``)."""
    p.add_argument("device", metavar="DEVICE", help=device_help() if hub_options else
                   "the CoolPro: coolpro[:ADDRESS], e.g. coolpro, coolpro:41")
    add_alias_args(p, hub_options=hub_options)


def add_alias_args(p: argparse.ArgumentParser, *, hub_options: bool = True,
                   note: str = "") -> None:
    """A DEVICE's alias options: --address, and with ``hub_options`` --channels
    and --humidity-unit; ``note`` ends each help text."""
    p.add_argument("--address", type=int, metavar="N",
                   help="the device's address, as in TYPE:ADDRESS (default: coolpro "
                        f"{maps.builtin('coolpro').device.default_address}, hub "
                        f"{maps.builtin('hub').device.default_address}){note}")
    if hub_options:
        p.add_argument("--channels", type=int, metavar="N",
                       help="hub channels, as in hub,channels=N (50 for firmware V1.07 and "
                            f"below; default 100){note}")
        p.add_argument("--humidity-unit", type=float, choices=[1, 0.1],
                       help=f"hub humidity unit in %%, as in hub,humidity_unit=U (default "
                            f"0.1){note}")


def alias_spec(spec: str, args: argparse.Namespace, known: KnownMaps | None = None) -> str:
    """``spec`` with what its alias options (``--address``, a map option's
    ``--channels``, ``--humidity-unit``) give written into it; a value given
    both ways must agree."""
    dev = parse_device(spec, known)  # checked against its map
    given: dict[str, Any] = dict(dev.options)
    if split_spec(spec)[1] is not None:
        given["address"] = dev.address
    out = spec.strip()
    for attr in ("address", "channels", "humidity_unit"):
        value = getattr(args, attr, None)
        if value is None:
            continue
        flag = "--" + attr.replace("_", "-")
        if attr != "address" and attr not in dev.map.device.options:
            raise InvalidArgument(f"{flag} is for a hub")
        if attr in given:
            if given[attr] != value:
                raise InvalidArgument(f"{spec!r} gives {attr} {given[attr]:g} and {flag} "
                                      f"{value:g}: give it once")
        elif attr == "address":
            head, comma, tail = out.partition(",")
            out = f"{head}:{value}{comma}{tail}"
        else:
            out += f",{attr}={value:g}"
    return out


def device_from_args(args: argparse.Namespace) -> DeviceConfig:
    """The device the positional spec and its alias options (``--address``,
    a map option's ``--channels``, ``--humidity-unit``) name; a value given
    both ways must agree."""
    return parse_device(alias_spec(args.device, args))


def parse_numbers(spec: str, low: int, high: int, what: str) -> list[int]:
    """``1-10,40`` -> the numbers (in the order given, without repeats), each
    within ``low..high``; a mistake is an InvalidArgument ``bad {what}``:
    the one parser of the ranges the commands take (``--range``, ``--show``,
    ``--channel``)."""
    out: list[int] = []
    seen: set[int] = set()
    try:
        for part in spec.split(","):
            lo, _, hi = part.strip().partition("-")
            a, b = int(lo), int(hi or lo)
            if not low <= a <= b <= high:
                raise ValueError
            for n in range(a, b + 1):
                if n not in seen:
                    seen.add(n)
                    out.append(n)
    except ValueError:
        raise InvalidArgument(f"bad {what}") from None
    return out


def parse_channels(spec: str, channels: int, flag: str = "--show") -> list[int]:
    """``1-10,40`` -> [1..10, 40], each within 1..channels."""
    return sorted(parse_numbers(spec, 1, channels, f"{flag} {spec!r}: channels 1..{channels}, "
                                                   "e.g. 1-20 or 1-10,40"))


def interruptible(fn: Callable[[], T]) -> T:
    """Run ``fn`` (blocking I/O) in a daemon thread and wait for it in short
    steps, so Ctrl-C ends the command at once whatever the reply timeout:
    the main thread gets KeyboardInterrupt within a few milliseconds, and a
    request still waiting for its reply is abandoned with the process."""
    result: list[T] = []
    error: list[BaseException] = []

    def target() -> None:
        try:
            result.append(fn())
        except BaseException as e:  # handed to the main thread
            error.append(e)

    t = threading.Thread(target=target, name="pymb-io", daemon=True)
    t.start()
    while t.is_alive():
        t.join(0.05)
    if error:
        raise error[0]
    return result[0]


def add_connection_args(p: argparse.ArgumentParser, *,
                        timeout: float = DEFAULT_TIMEOUT, tls: bool = True) -> None:
    """--port (with --ascii) / --tcp / --rtu-over-tcp / --udp, --baud, --parity,
    --timeout, and with ``tls`` the client's Modbus/TCP Security options
    (:func:`add_tls_args`)."""
    where = p.add_mutually_exclusive_group(required=True)
    where.add_argument("--port", metavar="PATH",
                       help="serial port, e.g. /dev/ttyUSB0 or /dev/serial/by-id/...")
    where.add_argument("--tcp", metavar="HOST:PORT",
                       help="a Modbus TCP gateway; mbaps://HOST[:PORT] for Modbus/TCP "
                            "Security (TLS, port 802)")
    where.add_argument("--rtu-over-tcp", metavar="HOST:PORT",
                       help="RTU frames over TCP: a transparent serial server (\"raw\" mode)")
    where.add_argument("--udp", metavar="HOST:PORT", help="Modbus over UDP (MBAP datagrams)")
    add_ascii_arg(p)
    add_serial_args(p)
    p.add_argument("--timeout", type=float, default=timeout,
                   help=f"seconds to wait for a reply (default {timeout:g})")
    if tls:
        add_tls_args(p)


def add_ascii_arg(p: argparse.ArgumentParser) -> None:
    """--ascii: Modbus ASCII on the --port line (:func:`ascii_line` checks it)."""
    p.add_argument("--ascii", action="store_true",
                   help="Modbus ASCII instead of RTU on the --port serial line")


def ascii_line(args: argparse.Namespace) -> bool:
    """True with --ascii, which needs --port (else InvalidArgument)."""
    on: bool = getattr(args, "ascii", False)
    if on and not args.port:
        raise InvalidArgument("--ascii is Modbus ASCII on a serial line: give it with --port PATH")
    return on


def add_serial_args(p: argparse.ArgumentParser) -> None:
    """--baud and --parity: the serial line's (--port PATH); :func:`serial_options`
    refuses them with any other transport and fills in their defaults."""
    p.add_argument("--baud", type=int, default=None,
                   help=f"the serial line's baud rate, with --port (default {DEFAULT_BAUD})")
    p.add_argument("--parity", default=None, choices=["N", "E", "O"],
                   help=f"the serial line's parity, with --port (default {DEFAULT_PARITY})")


def serial_options(args: argparse.Namespace) -> None:
    """Refuse --baud/--parity without a serial line (--port PATH: they would
    be ignored), then give them their defaults in ``args``. Once per command
    line: a command may make its client again (``config`` after a reset,
    ``log`` for a SunSpec discovery) with the defaults filled in."""
    if getattr(args, "serial_checked", False):
        return
    args.serial_checked = True
    if not getattr(args, "port", None):
        given = [f"--{k}" for k in ("baud", "parity") if getattr(args, k, None) is not None]
        if given:
            where = next((f"--{k.replace('_', '-')} {getattr(args, k)}"
                          for k in ("tcp", "rtu_over_tcp", "udp", "config")
                          if getattr(args, k, None)), "")
            if where.startswith("--config"):
                raise InvalidArgument(f"with --config, give {given[0]}'s value in the file's "
                                      "[[bus]] table")
            raise InvalidArgument(f"{given[0]} is for a serial line (--port PATH)"
                                  + (f", not {where}" if where else ""))
    if getattr(args, "baud", None) is None:
        args.baud = DEFAULT_BAUD
    if getattr(args, "parity", None) is None:
        args.parity = DEFAULT_PARITY


def add_tls_args(p: argparse.ArgumentParser) -> None:
    """--ca, --cert, --key, --server-name: for ``--tcp mbaps://HOST[:PORT]``."""
    tls = p.add_argument_group("Modbus/TCP Security (with --tcp mbaps://HOST[:PORT])")
    tls.add_argument("--ca", dest="tls_ca", metavar="FILE",
                     help="the CA that signed the server's certificate (PEM; default: the "
                          "system's trusted CAs)")
    tls.add_argument("--cert", dest="tls_cert", metavar="FILE",
                     help="this client's certificate (PEM)")
    tls.add_argument("--key", dest="tls_key", metavar="FILE", help="its private key (PEM)")
    tls.add_argument("--server-name", dest="tls_server_name", metavar="NAME",
                     help="the name the server's certificate must be made for (default: the "
                          "host connected to)")


def add_mqtt_access(g: argparse._ArgumentGroup, password_help: str) -> None:
    """--mqtt-user, --mqtt-password-file (``password_help``), --mqtt-ca,
    --mqtt-cert and --mqtt-key: a broker's access (pymb log, pymb collect)."""
    g.add_argument("--mqtt-user", metavar="NAME", help="user name")
    g.add_argument("--mqtt-password-file", metavar="FILE", help=password_help)
    g.add_argument("--mqtt-ca", metavar="FILE", help="CA certificate(s) to verify the broker")
    g.add_argument("--mqtt-cert", metavar="FILE", help="client certificate (with --mqtt-key)")
    g.add_argument("--mqtt-key", metavar="FILE", help="client certificate's private key")


def tls_for(args: argparse.Namespace, address: str | None, flag: str = "--tcp") -> TlsConfig | None:
    """The TLS settings of the options, which need ``address`` to be
    ``mbaps://...`` (None: no option given)."""
    given = any(getattr(args, f"tls_{k}", None) is not None
                for k in ("ca", "cert", "key", "server_name"))
    if given and not (address and is_mbaps(address)):
        where = f", not {flag} {address}" if address else ""
        raise InvalidArgument(f"--ca/--cert/--key/--server-name need --tcp "
                              f"mbaps://HOST[:PORT]{where}")
    return tls_from_args(args)


def tls_from_args(args: argparse.Namespace) -> TlsConfig | None:
    """The TLS settings the options give (None: no option given)."""
    given = {k: getattr(args, f"tls_{k}", None) for k in ("ca", "cert", "key", "server_name")}
    if all(v is None for v in given.values()):
        return None
    if given["key"] is not None and given["cert"] is None:
        raise InvalidArgument("--key needs --cert (the certificate it belongs to)")
    try:
        return TlsConfig(ca=given["ca"], cert=given["cert"], key=given["key"],
                         server_name=given["server_name"])
    except InvalidArgument as e:  # its words name the field: here, the option
        text = str(e)
        for field in ("server_name", "ca", "cert", "key"):
            if text.startswith(f"tls {field} "):
                text = "--" + field.replace("_", "-") + text[len(f"tls {field}"):]
        raise InvalidArgument(text) from None


def never_a_line(path: str) -> str | None:
    """What a serial port path is when it exists and can never open as a line
    (``"a directory"``, ``"a regular file"``): a mistake to say at the start;
    None for a device, or for a path that does not exist yet (an adapter to be
    plugged in, which the logger and the server open when it comes)."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return None
    return "a directory" if stat.S_ISDIR(mode) else "a regular file" if stat.S_ISREG(
        mode) else None


def make_client(args: argparse.Namespace, *, resolve: bool = True) -> Client:
    """The client the connection arguments describe (not yet open); a host
    name that does not resolve is said so (unless not ``resolve``: a plan
    made away from the plant's network)."""
    serial_options(args)
    on_ascii = ascii_line(args)
    if getattr(args, "udp", None):
        tls_for(args, args.udp, "--udp")  # refused: Modbus over UDP has no TLS
        host, port = parse_host_port(args.udp, what="--udp")
        why = unresolved(host) if resolve else None
        if why is not None:
            raise ModbusConnectionError(f"cannot connect to {args.udp}: {why}", port=args.udp)
        return UdpClient(host, port, timeout=args.timeout)
    if on_ascii:
        tls_for(args, None)
        return AsciiClient(args.port, args.baud, args.parity, timeout=args.timeout)
    for option, framing in (("tcp", False), ("rtu_over_tcp", True)):
        address = getattr(args, option, None)
        if not address:
            continue
        flag = "--" + option.replace("_", "-")
        tls = tls_for(args, address, flag)
        client = client_for_address(address, rtu_framing=framing, timeout=args.timeout,
                                    what=flag, tls=tls)
        why = unresolved(client.host) if resolve else None
        if why is not None:
            raise ModbusConnectionError(f"cannot connect to {address}: {why}", port=address)
        return client
    tls_for(args, None)
    return RtuClient(args.port, args.baud, args.parity, timeout=args.timeout)


def render(data: MapReading | CoolProIdentity) -> str:
    """A readable table with units of a hub's or a CoolPro's reading, or a
    CoolPro's identity; no-value states shown by name."""
    if isinstance(data, MapReading):
        return reading_text(data.map, data.values, data.states, data.unsupported)
    return "\n".join([
        f"{'Serial Number':<16} {data.serial_number}",
        f"{'Hardware':<16} rev {data.hardware_revision}",
        f"{'Firmware':<16} {data.firmware_version}",
        f"{'Manufactured':<16} {data.manufactured.isoformat()}",
    ])


def to_json(data: MapReading | CoolProIdentity) -> dict[str, Any]:
    """A JSON-ready dict of a hub's or a CoolPro's reading (None where there
    is no value), or of a CoolPro's identity."""
    if isinstance(data, MapReading):
        doc = reading_dict(data)
        if indexed(data.map, data.values):
            return doc
        return {**doc["values"], **{k: v for k, v in doc.items() if k != "values"}}
    return {"serial_number": data.serial_number, "hardware_revision": data.hardware_revision,
            "firmware_version": data.firmware_version,
            "manufactured": data.manufactured.isoformat()}


def print_json(obj: Any) -> None:
    """Print one JSON document."""
    json.dump(obj, sys.stdout, indent=2, allow_nan=False)
    sys.stdout.write("\n")


def add_map_arg(p: argparse.ArgumentParser, *, group: bool = False) -> None:
    """``--map FILE``, repeatable; with ``group``, also ``--group NAME``."""
    p.add_argument("--map", action="append", default=[], metavar="FILE", dest="maps",
                   help="a device map (pymb.map/1): its device.id becomes a device TYPE "
                        "(repeatable; the shipped maps need none)")
    if group:
        p.add_argument("--group", metavar="NAME",
                       help="a device read through a map: only the points of this polling "
                            "group (default: every readable point)")
