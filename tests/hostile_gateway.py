"""A scripted, hostile Modbus TCP gateway for the one-loop poller
(:mod:`pymb.logger.tcploop`), written from the Modbus TCP specification
([MB-TCP] 3.1.3: transaction id, protocol id 0, length, unit id), not from
pymb: :class:`Hostile` serves 127.0.0.1 and lets a test's ``script`` answer
each request (or lie, stall, close); :func:`poll` runs a
:class:`~pymb.logger.tcploop.TcpMapPoller` against it until a condition on
what it handed over holds (bounded) and returns what it handed over.
"""

from __future__ import annotations

import queue
import socket
import struct
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

from peerkit import mbap, registers

from pymb.logger.config import load_config
from pymb.logger.poller import Stats
from pymb.logger.tcploop import TcpMapPoller
from pymb.store import Event, Sample
from pymb.store.block import PollBlock

#: a holding-register map of two points at 0 and 1; a device is offline
#: after 3 failed polls and tried again every 0.5 s
HX_MAP = '''schema = "pymb.map/1"
[device]
id = "hx"
table = "holding"
[device.timing]
offline_after = 3
offline_retry = 0.5
[[point]]
name = "a"
address = 0
type = "u16"
[[point]]
name = "b"
address = 1
type = "u16"
'''

#: (transaction id, unit, function, address, count) of a read request
Request = tuple[int, int, int, int, int]
#: what a gateway does with the ``n``-th request of a connection (see :class:`Hostile`)
Script = Callable[[int, Request, socket.socket], bytes | None]


def good(tid: int, unit: int, fc: int, address: int, count: int) -> bytes:
    """The right reply to a read of registers: register ``a`` of unit ``u``
    holds ``100 * u + a``."""
    regs = [100 * unit + address + i for i in range(count)]
    return mbap(tid, unit, bytes((fc,)) + registers(regs))


class Hostile:
    """A TCP server on 127.0.0.1: ``script(n, request, conn)`` returns the
    bytes to send for the ``n``-th request of a connection (1-based; None:
    send nothing) or acts on ``conn`` itself. ``script=None``: every
    connection is closed as soon as it is accepted."""

    def __init__(self, script: Script | None, port: int = 0) -> None:
        self.script = script
        self.server = socket.create_server(("127.0.0.1", port))
        self.port = self.server.getsockname()[1]
        self.accepted: list[float] = []  #: when each connection was accepted (monotonic)
        self.done = threading.Event()
        self.thread = threading.Thread(target=self._accept, daemon=True)
        self.thread.start()

    def _accept(self) -> None:
        self.server.settimeout(0.05)
        while not self.done.is_set():
            try:
                conn, _ = self.server.accept()
            except TimeoutError:
                continue
            self.accepted.append(time.monotonic())
            if self.script is None:
                conn.close()
                continue
            threading.Thread(target=self._serve, args=(conn,), daemon=True).start()

    def _requests(self, conn: socket.socket) -> Iterator[Request]:
        buf = b""
        conn.settimeout(0.1)
        while not self.done.is_set():
            try:
                data = conn.recv(4096)
            except TimeoutError:
                continue
            except OSError:
                return
            if not data:
                return
            buf += data
            while len(buf) >= 12:
                tid, _, _, unit, fc, address, count = struct.unpack(">HHHBBHH", buf[:12])
                buf = buf[12:]
                yield tid, unit, fc, address, count

    def _serve(self, conn: socket.socket) -> None:
        assert self.script is not None
        with conn:
            for n, req in enumerate(self._requests(conn), 1):
                try:
                    out = self.script(n, req, conn)
                    if out:
                        conn.sendall(out)
                except OSError:
                    return

    def close(self) -> None:
        """Stop serving."""
        self.done.set()
        self.thread.join(5.0)
        self.server.close()


@dataclass
class Handed:
    """What a poller handed over, and its counts."""

    #: its samples, those of the blocks of polls its C part carried included
    samples: list[Sample] = field(default_factory=list)
    events: list[Event] = field(default_factory=list)
    stats: Stats = field(default_factory=Stats)
    blocks: list[PollBlock] = field(default_factory=list)  #: those blocks

    def kinds(self) -> list[str]:
        """The kinds of the events, in order."""
        return [e.kind for e in self.events]

    def values(self) -> set[tuple[int, tuple[int, ...]]]:
        """(unit, registers) of every sample."""
        return {(s.device.address, tuple(s.data.registers))  # type: ignore[union-attr]
                for s in self.samples}


def poll(tmp: Path, ports: list[int | str], until: Callable[[Handed], bool], *,
         units: tuple[int, ...] = (1,), bus: str = "timeout = 0.2\ninterval = 0.05\n",
         within: float = 20.0, points: str = "") -> Handed:
    """Poll ``units`` (the HX map) behind each port in ``ports`` (a bus
    each; a str port is a ``host:port``) with one TcpMapPoller until
    ``until(handed)`` or ``within`` seconds; the poller is stopped and
    must end. ``points``: more ``[[point]]`` tables for the map."""
    (tmp / "hx.toml").write_text(HX_MAP + points)
    text = 'maps = ["hx.toml"]\n'
    for port in ports:
        where = port if isinstance(port, str) else f"127.0.0.1:{port}"
        text += f'[[bus]]\ntcp = "{where}"\n{bus}'
        text += "".join(f'[[bus.device]]\ntype = "hx"\naddress = {u}\n' for u in units)
    (tmp / "log.toml").write_text(text)
    buses = load_config(tmp / "log.toml").buses
    q: queue.Queue[list[Sample | Event | PollBlock]] = queue.Queue()
    stop = threading.Event()
    got = Handed()
    poller = TcpMapPoller(buses, q, stop, got.stats)
    poller.start()
    deadline = time.monotonic() + within
    try:
        while time.monotonic() < deadline and not until(got):
            try:
                items = q.get(timeout=0.1)
            except queue.Empty:
                continue
            got.blocks += [i for i in items if isinstance(i, PollBlock)]
            got.samples += [s for i in items
                            for s in (i.samples() if isinstance(i, PollBlock) else [i])
                            if isinstance(s, Sample)]
            got.events += [e for e in items if isinstance(e, Event)]
    finally:
        stop.set()
        poller.join(5.0)
    assert not poller.is_alive()
    return got
