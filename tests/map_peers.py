"""Peers for the map tests that are not pymb: a scripted responder (RTU on a
pseudo-terminal, Modbus TCP on 127.0.0.1) that has only the registers it is
given, answers a read touching any other with exception 02 and a read longer
than its limit with exception 03, and records every request with the time it
arrived and the time its reply went out; and the sparse pymodbus server
(tests/pymodbus_sparse_server.py) in its own process."""

from __future__ import annotations

import json
import struct
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from peerkit import Reply
from peers import PtyPeer, TcpPeer

HERE = Path(__file__).resolve().parent
FC_TABLE = {1: "coil", 2: "discrete", 3: "holding", 4: "input"}


@dataclass
class Logged:
    """One request the peer received."""

    arrived: float  #: time.monotonic() when the whole frame was in
    replied: float  #: time.monotonic() just before the reply was written
    slave: int
    function: int
    address: int
    count: int  #: registers or bits asked for (0 for a write)
    refused: int  #: exception code sent, 0 for none


class Refusing:
    """Mixed into a peer: only ``have[table]`` addresses exist; every request
    is logged in ``log``."""

    def setup(self, have: dict[str, set[int]], max_count: int = 125) -> None:
        self.have = have
        self.max_count = max_count
        self.log: list[Logged] = []

    def reply_for(self, slave: int, pdu: bytes) -> Reply:
        arrived = time.monotonic()
        fc = pdu[0]
        address, count = struct.unpack(">HH", pdu[1:5]) if len(pdu) >= 5 else (0, 0)
        refused = 0
        if fc in FC_TABLE:
            limit = self.max_count if fc > 2 else 2000
            have = self.have.get(FC_TABLE[fc], set())
            if count > limit:
                refused = 3
            elif any(a not in have for a in range(address, address + count)):
                refused = 2
        else:
            count = 0
        if refused:
            reply = [(0.0, self.frame(slave, bytes((fc | 0x80, refused))))]  # type: ignore[attr-defined]
        else:
            reply = super().reply_for(slave, pdu)  # type: ignore[misc]
        self.log.append(Logged(arrived, time.monotonic(), slave, fc, address, count, refused))
        return reply

    def reads(self) -> list[tuple[str, int, int]]:
        """The read requests so far as (table, address, count)."""
        return [(FC_TABLE[r.function], r.address, r.count) for r in self.log
                if r.function in FC_TABLE]


class RefusingPtyPeer(Refusing, PtyPeer):
    """RTU over a pseudo-terminal (``port``)."""

    def __init__(self, have: dict[str, set[int]], max_count: int = 125) -> None:
        PtyPeer.__init__(self)
        self.setup(have, max_count)


class RefusingTcpPeer(Refusing, TcpPeer):
    """Modbus TCP on 127.0.0.1 (``port``)."""

    def __init__(self, have: dict[str, set[int]], max_count: int = 125) -> None:
        TcpPeer.__init__(self)
        self.setup(have, max_count)


@dataclass
class SparseServer:
    """The sparse pymodbus server: its port, and the requests it logged."""

    port: int
    proc: subprocess.Popen[str]

    def requests(self) -> list[tuple[float, bytes]]:
        """(time, packet) of every packet received so far; stops the server."""
        self.proc.kill()
        out, _ = self.proc.communicate(timeout=10)
        return [(float(t), bytes.fromhex(h)) for line in out.splitlines()
                if line.startswith("REQ") for _, t, h in [line.split()]]


@contextmanager
def sparse_pymodbus(mode: str, spec: dict[str, dict[int, int]]) -> Iterator[SparseServer]:
    """Run the sparse pymodbus server (unit 5) with ``spec``'s registers."""
    text = json.dumps({t: {str(a): v for a, v in regs.items()} for t, regs in spec.items()})
    proc = subprocess.Popen([sys.executable, str(HERE / "pymodbus_sparse_server.py"), mode, text],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline().split()
        assert line, "the server printed nothing"
        assert line[0] == "READY", line
        yield SparseServer(int(line[1]), proc)
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait(10)
