"""The simulator a user starts: devices, a bus, a transport, faults.

:class:`Simulator` runs the bus in a background thread of the calling
process, so the caller can steer the devices, the faults and the clock
while a master talks to it. :class:`SimulatorProcess` runs ``python -m pymb
simulate`` as a child process instead (for benchmarks: the simulator then
never competes with the master for the GIL).
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterable, Mapping, Sequence
from types import TracebackType

from pymb.child import Child, ChildError, pymb_argv_here
from pymb.client import parse_host_port
from pymb.devices.mapspec import map_types, parse_map_device, unknown_device
from pymb.devices.spec import split_spec
from pymb.errors import InvalidArgument
from pymb.maps import Map
from pymb.maps.model import did_you_mean
from pymb.sim.base import SIM_KEYS
from pymb.sim.bus import Bus, BusStats
from pymb.sim.clock import SimClock
from pymb.sim.devices import CoolProDevice, Device, HubDevice
from pymb.sim.faults import Faults
from pymb.sim.mapsim import MapSimDevice
from pymb.sim.rtu import RtuServer
from pymb.sim.server import SimServer
from pymb.sim.tcp import TcpServer, format_ports, parse_ports

__all__ = ["HOOKS", "TRANSPORTS", "Simulator", "SimulatorProcess", "make_device"]

TRANSPORTS = ("pty", "serial", "tcp", "rtu-over-tcp")
#: the devices with behaviours of their own, by map id; any other map's device is a MapSimDevice
HOOKS: dict[str, type[MapSimDevice]] = {"coolpro": CoolProDevice, "hub": HubDevice}


def map_sim_device(spec: str, known: Mapping[str, Map], *, seed: int = 0,
                   clock: SimClock | None = None, baud: int | None = None,
                   hooks: Mapping[str, type[MapSimDevice]] | None = None
                   ) -> MapSimDevice | None:
    """A simulated device from ``TYPE[:ADDRESS][,key=value...]`` when TYPE
    is a map's id in ``known`` or in ``hooks`` (a device with behaviours of
    its own; None otherwise): the map's options, :data:`SIM_KEYS` and the
    device's own :attr:`MapSimDevice.spec_keys`. ``baud`` (the bus's speed)
    applies unless the spec names one."""
    kind, _, opts = split_spec(spec)
    cls = (hooks or {}).get(kind, MapSimDevice)
    m = cls.builtin_map or known.get(kind)
    if m is None:
        return None
    keys = {**SIM_KEYS, **cls.spec_keys}
    allowed = [*keys, *(o for o in m.device.options if o not in cls.refused)]
    args: dict[str, object] = {} if baud is None else {"baud": baud}
    rest = []
    for key, eq, value in opts:
        if key in cls.refused:
            raise InvalidArgument(f"{spec!r}: {cls.refused[key]}")
        if key not in keys:
            if key not in allowed and key != "name":
                raise InvalidArgument(
                    f"{spec!r}: unknown key {key!r}; {kind} takes "
                    f"{', '.join(k + '=...' for k in allowed)}{did_you_mean(key, allowed)}")
            rest.append(f"{key}={value}" if eq else key)
            continue
        arg, parse, what = keys[key]
        try:
            args[arg] = parse(value)
        except (ValueError, KeyError):
            raise InvalidArgument(f"{spec!r}: bad value for {key}: {value!r} ({what})") from None
    target = parse_map_device(",".join([spec.split(",")[0], *rest]), {kind: m})
    assert target is not None
    try:
        return cls._from_spec(target, args, seed=seed, clock=clock)
    except InvalidArgument as e:
        raise InvalidArgument(f"{spec!r}: {e}") from None


def make_device(spec: str, *, seed: int = 0, clock: SimClock | None = None,
                baud: int | None = None, known: Mapping[str, Map] | None = None) -> Device:
    """A device from ``TYPE[:ADDRESS][,key=value...]``: ``coolpro``,
    ``hub`` or the id of any map in ``known`` (default: the shipped maps).

    Every device takes its map's options (the hub's ``humidity_unit``, or
    ``humidity``: 0.1 or 1) and the simulator's keys: ``firmware`` (points
    need their ``min_firmware``; a hub on 1.07 has 50 channels), ``delay``
    (seconds before each reply, or LOW-HIGH), ``baud`` and ``dynamic``
    (0/1). The CoolPro also takes ``gap`` (its delay), ``serial``,
    ``hardware`` and ``uptime`` (seconds). ``baud`` (the bus's speed)
    applies unless the spec names one. Example: ``hub:250,firmware=2.18``,
    ``eastron-sdm630:3``.
    """
    known = map_types() if known is None else known
    dev = map_sim_device(spec, known, seed=seed, clock=clock, baud=baud, hooks=HOOKS)
    if dev is None:
        raise unknown_device(spec, list(known))
    return dev


class Simulator:
    """Simulated devices on one bus, served on a pseudo-terminal, a serial
    port or Modbus TCP, from a background thread.

    ``devices``: specs (see :func:`make_device`: ``coolpro``, ``hub`` or a
    shipped map's id) or :class:`Device` objects
    (give those ``clock=sim.clock`` yourself if the simulator should steer
    their time); default one CoolPro. ``transport``: ``"pty"`` (default),
    ``"serial"`` (``port`` names it), ``"tcp"`` or ``"rtu-over-tcp"`` (RTU
    frames on a TCP socket, as a raw serial server passes them) (``host``, ``tcp_port``; 0
    picks a free port). ``baud``: the line's speed; every device is set to
    it and each frame takes its real wire time (None: 9600, no emulation).
    ``seed``: values and probabilistic faults; ``faults``: a :class:`Faults`
    or command-line specs (``"late:0.1,delay=1.5"``). ``link``: for a pty, a
    symbolic link that always points at the current pseudo-terminal (True:
    one in a private temporary directory, the default; a path; False: none):
    :attr:`port` is that link, so a client survives :meth:`unplug`.

    Use as a context manager::

        with Simulator(["coolpro", "hub:250"]) as sim:
            with pymb.RtuClient(sim.port, 9600, slave=40) as c: ...
            sim.device(250).set_offline(3)
            sim.faults.inject("bad_crc", address=40)
    """

    def __init__(
        self,
        devices: Iterable[str | Device] = ("coolpro",),
        *,
        transport: str = "pty",
        port: str | None = None,
        host: str = "127.0.0.1",
        tcp_port: int = 0,
        tcp_ports: list[int] | None = None,
        baud: int | None = None,
        seed: int = 0,
        faults: Faults | Sequence[str] | None = None,
        clock: SimClock | None = None,
        link: bool | str = True,
        check_line: bool = True,
        trace: bool = False,
    ) -> None:
        if transport not in TRANSPORTS:
            raise InvalidArgument(f"transport must be one of {', '.join(TRANSPORTS)}, "
                                  f"got {transport!r}")
        if transport == "serial" and not port:
            raise InvalidArgument("transport 'serial' needs port=PATH")
        if isinstance(devices, str):
            devices = [devices]
        self.clock = clock if clock is not None else SimClock()
        self.seed = seed
        built = [d if isinstance(d, Device) else
                 make_device(d, seed=seed * 1009 + i, clock=self.clock, baud=baud)
                 for i, d in enumerate(devices)]
        if not built:
            raise InvalidArgument("a simulator needs at least one device")
        seen: dict[int, Device] = {}
        for d in built:
            if d.address in seen:
                raise InvalidArgument(f"two devices at address {d.address}: "
                                      f"{seen[d.address].kind} and {d.kind}")
            seen[d.address] = d
        if baud is not None and not baud > 0:
            raise InvalidArgument(f"baud must be a positive number of bit/s, got {baud}")
        if isinstance(faults, Faults):
            self.faults = faults
        else:
            self.faults = Faults(seed)
            for spec in faults or ():
                self.faults.add(spec)
        self.bus = Bus(built, self.faults, check_line=check_line, trace=trace)
        self.transport = transport
        self.baud = baud
        self._link_opt = link
        self._tmpdir: str | None = None
        self._serial = port
        self._host = host
        self._tcp_port = tcp_port
        self._tcp_ports = tcp_ports
        self._server: SimServer | None = None

    # -- life cycle ---------------------------------------------------------------------

    def start(self) -> Simulator:
        """Open the port and start serving; returns self."""
        if self._server is not None:
            return self
        line = self.baud or self.bus.devices[0].baud
        server: SimServer
        if self.transport in ("tcp", "rtu-over-tcp"):
            server = TcpServer(self.bus, self._host, self._tcp_port, emulate_baud=self.baud,
                               rtu_framing=self.transport == "rtu-over-tcp",
                               ports=self._tcp_ports)
        else:
            link = None
            if self.transport == "pty" and self._link_opt:
                if isinstance(self._link_opt, str):
                    link = self._link_opt
                else:
                    self._tmpdir = tempfile.mkdtemp(prefix="pymb-sim-")
                    link = os.path.join(self._tmpdir, "ttySIM0")
            server = RtuServer(self.bus, baud=line, serial_port=self._serial,
                               emulate=self.baud is not None and self.transport == "pty",
                               link=link)
        try:
            server.start()
        except BaseException:
            self._cleanup_tmp()
            raise
        self._server = server
        return self

    def stop(self) -> None:
        """Stop serving and remove the port and link; safe to call twice."""
        server, self._server = self._server, None
        if server is not None:
            server.stop()
        self._cleanup_tmp()

    def _cleanup_tmp(self) -> None:
        if self._tmpdir is not None:
            shutil.rmtree(self._tmpdir, ignore_errors=True)
            self._tmpdir = None

    def __enter__(self) -> Simulator:
        return self.start()

    def __exit__(self, et: type[BaseException] | None, ev: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.stop()

    def __repr__(self) -> str:
        state = self.endpoint if self._server is not None else "stopped"
        kinds = ", ".join(f"{d.kind}:{d.address}" for d in self.bus.devices)
        return f"<Simulator [{kinds}] {self.transport} {state}>"

    # -- where to connect -----------------------------------------------------------------

    def _running(self) -> SimServer:
        if self._server is None:
            raise RuntimeError("the simulator is not running: use `with Simulator(...)` "
                               "or call start()")
        return self._server

    @property
    def port(self) -> str:
        """The path a master opens: the stable link (pty), the pseudo-terminal
        itself when there is no link, or the serial port."""
        server = self._running()
        if not isinstance(server, RtuServer):
            raise RuntimeError("a TCP simulator has no serial port: use host and tcp_port")
        if server.link:
            return server.link
        return server.path or ""

    @property
    def pty_path(self) -> str | None:
        """The current pseudo-terminal (``/dev/pts/N``), None while unplugged."""
        server = self._running()
        return server.path if isinstance(server, RtuServer) else None

    @property
    def host(self) -> str:
        """The TCP server's address."""
        return self._host

    @property
    def tcp_port(self) -> int:
        """The TCP server's port (the one picked when 0 was asked; the first of many)."""
        return self.tcp_ports[0]

    @property
    def tcp_ports(self) -> list[int]:
        """Every port the TCP server answers on (the same devices on each)."""
        server = self._running()
        if not isinstance(server, TcpServer):
            raise RuntimeError("not a TCP simulator: use port")
        return list(server.ports)

    @property
    def endpoint(self) -> str:
        """What the command line prints: the port path, or ``HOST:PORT``
        (``HOST:FIRST-LAST`` or ``HOST:P1,P2,...`` for many ports)."""
        server = self._running()
        if isinstance(server, TcpServer):
            host = f"[{self._host}]" if ":" in self._host else self._host
            return f"{host}:{format_ports(server.ports)}"
        return self.port

    # -- control --------------------------------------------------------------------------

    @property
    def devices(self) -> tuple[Device, ...]:
        """The devices on the bus."""
        return self.bus.devices

    def device(self, address: int) -> Device:
        """The device answering at ``address`` now (a CoolPro moves at reset)."""
        d = self.bus.device(address)
        if d is None:
            raise KeyError(f"no device at address {address}; have "
                           f"{', '.join(str(x.address) for x in self.bus.devices)}")
        return d

    @property
    def stats(self) -> BusStats:
        """The bus's counters (requests, replies, service time)."""
        return self.bus.stats

    def unplug(self, seconds: float | None = None) -> None:
        """Make the port disappear, as a pulled USB adapter: a master's
        reads and writes fail (EIO), the link is removed. Back after
        ``seconds``, or at :meth:`replug`."""
        self._running().unplug(seconds)

    def replug(self) -> None:
        """Bring the port back: a new pseudo-terminal, the link re-pointed."""
        self._running().replug()

    @property
    def plugged(self) -> bool:
        """False while unplugged."""
        return self._running().plugged


class SimulatorProcess:
    """``python -m pymb simulate ARGS`` as a child process.

    ``args``: the command line after ``simulate`` (e.g. ``["coolpro", "hub",
    "--tcp", "127.0.0.1:0"]``). The endpoint is the child's first stdout
    line. Stopped with SIGTERM (then SIGKILL) on exit. ``quiet`` drops the
    child's stderr.
    """

    def __init__(self, args: Sequence[str], *, timeout: float = 10.0,
                 quiet: bool = False) -> None:
        self.args = list(args)
        self.timeout = timeout
        self.quiet = quiet  #: drop the child's stderr (its banner and summary)
        self.endpoint = ""
        self._child: Child | None = None

    def start(self) -> SimulatorProcess:
        """Start the child and wait for its endpoint line."""
        name = f"pymb simulate {' '.join(self.args)}"
        # Started where the caller is: relative paths (--link) mean what they say.
        self._child = Child(name, pymb_argv_here("simulate", *self.args), stdin=False,
                            stderr="drop" if self.quiet else "inherit", cwd=None)
        try:
            self.endpoint = self._child.readline(self.timeout).strip()
        except ChildError as e:
            self.stop()
            raise ChildError(f"{name} gave no endpoint within {self.timeout:g} s ({e})") from None
        return self

    @property
    def port(self) -> str:
        """The endpoint as a port path."""
        return self.endpoint

    @property
    def host(self) -> str:
        """The TCP endpoint's host."""
        return parse_host_port(self.endpoint)[0]

    @property
    def tcp_port(self) -> int:
        """The TCP endpoint's port (the first, when it serves many)."""
        return self.tcp_ports[0]

    @property
    def tcp_ports(self) -> list[int]:
        """Every port of the TCP endpoint (``--tcp FIRST-LAST`` or ``--count N``)."""
        return parse_ports(self.endpoint.rpartition(":")[2])

    def stop(self) -> int | None:
        """Stop the child (SIGTERM, then SIGKILL); returns its exit code."""
        child, self._child = self._child, None
        return None if child is None else child.stop(term_wait=5.0)

    def __enter__(self) -> SimulatorProcess:
        return self.start()

    def __exit__(self, et: type[BaseException] | None, ev: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.stop()
