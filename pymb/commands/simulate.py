"""``pymb simulate``: simulated devices on a pseudo-terminal, a port or TCP.

The first line on stdout is where a master connects (a path, or
``HOST:PORT``), flushed at once; everything else goes to stderr. Runs until
SIGINT or SIGTERM, then exits 0.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import signal
import stat
import sys
import termios
import time
from types import FrameType

from pymb import maps
from pymb.client import parse_host_port
from pymb.commands._common import add_map_arg
from pymb.devices.mapspec import map_types
from pymb.errors import InvalidArgument, ModbusConnectionError
from pymb.sim.clock import SimClock
from pymb.sim.devices import Device
from pymb.sim.faults import KINDS
from pymb.sim.mapsim import MapSimDevice
from pymb.sim.simulator import Simulator, make_device
from pymb.sim.tcp import MAX_PORTS, parse_ports

__all__ = ["add_arguments", "run"]

_EPILOG = f"""\
devices: KIND[:ADDRESS][,key=value...]
  every device          keys: the map's options, firmware (points need their
                        min_firmware), delay (s before each reply, or LOW-HIGH), baud,
                        dynamic (0/1)
  coolpro (address 40)  also gap (s, default 0.008), serial, hardware, uptime (s)
  hub (address 1)       firmware 1.07 and below: 50 channels; also humidity (0.1 or 1,
                        as humidity_unit: the unit on every channel)
  a map's id            a shipped map (eastron-sdm120, ...) or one given with --map FILE:
                        values from each point's example, or a seeded model; registers
                        the map does not declare answer exception 02
faults: KIND[:PROBABILITY][,key=value...]  (probability 1 when omitted)
  kinds: {', '.join(KINDS)}
  keys: delay, code, keep, extra (hex), to, seconds, bits, channels (3+4), address
examples:
  pymb simulate coolpro hub
  pymb simulate coolpro:41 hub:250,firmware=1.07 --baud 19200
  pymb simulate hub --tcp 127.0.0.1:5020 --fault busy:0.1 --fault late:0.05,delay=1
  pymb simulate --map meter.toml my-meter:3 --tcp 5020
  pymb simulate eastron-sdm630 --tcp 127.0.0.1:5020-5119   (100 TCP devices)
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Register ``simulate``'s arguments."""
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.epilog = _EPILOG
    parser.add_argument("devices", nargs="*", metavar="DEVICE",
                        help="devices on the bus (default: each --map's device at its "
                             "default address, or without --map: coolpro hub)")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--pty", action="store_true",
                       help="serve on a new pseudo-terminal and print its path (default)")
    where.add_argument("--port", metavar="PATH", help="serve on a real serial port")
    where.add_argument("--tcp", metavar="[HOST:]PORT",
                       help="serve Modbus TCP (host 127.0.0.1 unless named; port 0: any); "
                            "FIRST-LAST serves the same devices on each port of the range")
    where.add_argument("--rtu-over-tcp", metavar="[HOST:]PORT",
                       help="serve RTU frames over TCP, as a transparent serial server "
                            "(\"raw\" gateway) does (host 127.0.0.1 unless named; port 0: any)")
    parser.add_argument("--count", type=int, metavar="N",
                        help="with --tcp PORT: serve the same devices on N ports, PORT to "
                             "PORT+N-1 (port 0: N free ports), as N TCP devices")
    parser.add_argument("--baud", type=int, metavar="N",
                        help="line speed: every device is set to it and each frame takes "
                             "its real wire time (default 9600, no emulation)")
    parser.add_argument("--seed", type=int, default=0,
                        help="seed of the values and of the faults (default 0)")
    parser.add_argument("--fault", action="append", default=[], metavar="SPEC",
                        help="inject a fault by probability (repeatable)")
    add_map_arg(parser)
    parser.add_argument("--link", metavar="PATH",
                        help="keep a symbolic link at PATH pointing at the pseudo-terminal "
                             "and print it instead")
    parser.add_argument("--any-speed", action="store_true",
                        help="answer whatever speed the master sets on the pty")
    parser.add_argument("-v", "--verbose", action="store_true",
                        help="log every frame and fault to stderr")


def _tcp_address(text: str, flag: str = "--tcp") -> tuple[str, int]:
    return parse_host_port(text, what=flag, port_only=True)


def tcp_ports(text: str, count: int | None) -> tuple[str, list[int] | None]:
    """``--tcp [HOST:]FIRST-LAST`` or ``--tcp [HOST:]PORT --count N`` ->
    ``(host, ports)``; ports None for one port (the plain ``--tcp``)."""
    head, sep, tail = text.rpartition(":")
    if "-" in tail:
        if count is not None:
            raise InvalidArgument("give --tcp FIRST-LAST or --tcp PORT --count N, not both")
        ports = parse_ports(tail)
        return _tcp_address(f"{head}{sep}{ports[0]}")[0], ports
    host, port = _tcp_address(text)
    if count is None:
        return host, None
    if not 1 <= count <= MAX_PORTS:
        raise InvalidArgument(f"--count must be 1..{MAX_PORTS}, got {count}")
    if port and port + count - 1 > 65535:
        raise InvalidArgument(f"--tcp {port} --count {count} runs past port 65535")
    return host, [port + i if port else 0 for i in range(count)]


def check_link(path: str) -> None:
    """``--link PATH`` replaces only a link pymb made (one to a pseudo-terminal)."""
    if not os.path.lexists(path):
        parent = os.path.dirname(os.path.abspath(path))
        if not os.path.isdir(parent):
            raise InvalidArgument(f"--link {path}: no such directory {parent}")
        return
    if os.path.islink(path) and os.readlink(path).startswith("/dev/pts/"):
        return  # a link to a pseudo-terminal: pymb's, left by a simulator
    what = "a directory" if os.path.isdir(path) else "a link elsewhere" if os.path.islink(
        path) else "a file"
    raise InvalidArgument(f"--link {path} exists and is {what}: refusing to replace it; "
                          "give a path that does not exist")


def check_serial_port(path: str) -> None:
    """``--port PATH`` must be a terminal device."""
    try:
        st = os.stat(path)
    except OSError as e:
        raise ModbusConnectionError(f"cannot serve on {path}: {e.strerror}", errno=e.errno,
                                    port=path) from None
    if not stat.S_ISCHR(st.st_mode):
        what = "a directory" if stat.S_ISDIR(st.st_mode) else "a regular file" if \
            stat.S_ISREG(st.st_mode) else "not a character device"
        raise InvalidArgument(f"--port {path} is {what}, not a serial port")


def _hint(dev: Device, where: str, tcp: tuple[str, int] | None) -> str:
    if tcp is not None:
        line = f"mbpoll -m tcp -p {tcp[1]} -a {dev.address}"
        target = tcp[0]
    else:
        line = f"mbpoll -m rtu -b {dev.baud} -P none -a {dev.address}"
        target = where
    # the first request of the map's first group (its every point without groups)
    first = next(iter(dev.map.plan(next(iter(dev.map.groups), None))), None) if \
        isinstance(dev, MapSimDevice) else None
    if first is not None:
        t = {"coil": 0, "discrete": 1, "input": 3, "holding": 4}[first.table]
        return f"{line} -t {t} -0 -r {first.address} -c {min(first.count, 10)} -1 {target}"
    return line


def _devices(args: argparse.Namespace, clock: SimClock) -> list[Device]:
    """The devices the specs name (coolpro, hub or a map's id)."""
    known = map_types(getattr(args, "maps", []))
    # no DEVICE: each --map's device at its default address, else a CoolPro and a hub
    given = [i for i in known if i not in maps.builtin_ids()]
    specs = args.devices or given or ["coolpro", "hub"]
    return [make_device(spec, seed=args.seed * 1009 + i, clock=clock, baud=args.baud,
                        known=known) for i, spec in enumerate(specs)]


def run(args: argparse.Namespace) -> int:
    """Run the simulator until SIGINT or SIGTERM; 0 on a clean stop."""
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="pymb simulate: %(message)s", stream=sys.stderr)
    rot = getattr(args, "rtu_over_tcp", None)
    many: list[int] | None = None
    if args.count is not None and not args.tcp:
        raise InvalidArgument("--count is for --tcp only")
    if args.tcp:
        host, many = tcp_ports(args.tcp, args.count)
        tcp: tuple[str, int] | None = (host, many[0] if many else _tcp_address(args.tcp)[1])
    else:
        tcp = _tcp_address(rot, "--rtu-over-tcp") if rot else None
    transport = ("tcp" if args.tcp else "rtu-over-tcp" if rot else
                 "serial" if args.port else "pty")
    if args.link and transport != "pty":
        raise InvalidArgument("--link is for --pty only")
    if args.link:
        check_link(args.link)
    if args.port:
        check_serial_port(args.port)
    clock = SimClock()
    sim = Simulator(
        _devices(args, clock),
        clock=clock,
        transport=transport,
        port=args.port,
        host=tcp[0] if tcp else "127.0.0.1",
        tcp_port=tcp[1] if tcp else 0,
        tcp_ports=many,
        baud=args.baud,
        seed=args.seed,
        faults=args.fault,
        link=args.link or False,
        check_line=not args.any_speed,
        trace=args.verbose,
    )
    # A flag, not a threading.Event: Event.set() from a handler can wait for
    # the event's lock held by this same (main) thread inside Event.wait().
    stopped = [False]

    def on_signal(signum: int, frame: FrameType | None) -> None:
        stopped[0] = True

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        try:
            sim.start()
        except termios.error as e:
            raise InvalidArgument(f"--port {args.port} is not a serial port: "
                                  f"{e.args[-1]}") from None
        except OSError as e:
            where = args.port or args.tcp or rot or "a pseudo-terminal"
            raise ModbusConnectionError(f"cannot serve on {where}: {e.strerror or e}",
                                        errno=e.errno, port=where) from None
        endpoint = sim.endpoint
        if tcp is not None:  # the port bound (--tcp HOST:0 asks for any free one)
            tcp = (tcp[0], sim.tcp_port)
        with contextlib.suppress(BrokenPipeError):
            print(endpoint, flush=True)
        for dev in sim.devices:
            print(f"  {dev.describe()}", file=sys.stderr)
            if transport != "rtu-over-tcp":  # mbpoll has no RTU-over-TCP mode
                print(f"    try: {_hint(dev, endpoint, tcp)}", file=sys.stderr)
        if args.fault:
            print(f"  faults: {', '.join(args.fault)} (seed {args.seed})", file=sys.stderr)
        print("  Ctrl-C or SIGTERM stops it", file=sys.stderr, flush=True)
        while not stopped[0]:
            time.sleep(0.1)
    finally:
        sim.stop()
        for s, handler in previous.items():
            signal.signal(s, handler)
    counts = {k: v for k, v in sim.faults.counts.items() if v}
    stats = sim.stats
    print(f"pymb simulate: {stats.requests} requests, {stats.replies} replies"
          + (f", faults {counts}" if counts else ""), file=sys.stderr)
    return 0
