"""Write commands reach every logged device by its map, the CoolPro and the
hub too (no table of types): a bus thread's targets, against a simulated
line, and a write to the CoolPro's configuration through the poller's own
device, read back from the simulator."""

from __future__ import annotations

import contextlib
import queue
import socket
import struct
import threading
import time
from pathlib import Path

from hostile_gateway import Hostile, Request
from peerkit import mbap, registers

from pymb.devices.deviceconfig import parse_device
from pymb.devices.mapwrite import WriteBudget
from pymb.logger.config import BusConfig, load_config
from pymb.logger.poller import BusPoller
from pymb.logger.stats import Stats
from pymb.logger.targets import write_targets
from pymb.logger.tcploop import TcpMapPoller
from pymb.sim import Simulator, SimulatorProcess
from pymb.store import Event, Sample
from pymb.store.block import PollBlock


def test_the_coolpro_and_the_hub_are_write_targets_as_any_map_device() -> None:
    with Simulator(["coolpro", "hub:250"], seed=2) as sim:
        bus = BusConfig("b", port=sim.port, interval=0.2,
                        devices=[parse_device("coolpro"), parse_device("hub:250,channels=5")])
        out: queue.Queue[list[Sample | Event | PollBlock]] = queue.Queue()
        stop = threading.Event()
        poller = BusPoller(bus, out, stop, Stats())
        poller.start()
        try:
            targets = write_targets([poller], WriteBudget())
            assert sorted(targets) == ["coolpro-40", "hub-250"]
            assert targets["coolpro-40"].map.id == "coolpro"
            deadline = time.monotonic() + 30
            while targets["coolpro-40"].device() is None and time.monotonic() < deadline:
                time.sleep(0.05)
            dev = targets["coolpro-40"].device()
            assert dev is not None
            assert not targets["coolpro-40"].offline()
            dev.write("baud_rate_index", 2)
            assert dev.read("baud_rate_index") == {"baud_rate_index": 2}
            assert not [p for p in targets["hub-250"].map.points.values() if p.writable]
        finally:
            stop.set()
            poller.join(10)
    assert not poller.is_alive()


WRITABLE = '''schema = "pymb.map/1"
[device]
id = "wr"
table = "holding"
[[point]]
name = "a"
address = 0
type = "u16"
[[point]]
name = "setpoint"
address = 1
type = "u16"
access = "rw"
[[point]]
name = "b"
address = 300
type = "u16"
'''


def test_a_write_reaches_a_device_polled_flat_out_between_two_polls(tmp_path: Path) -> None:
    """Flat out and pipelined, the loop's C part carries the device's polls;
    a write command borrows its connection (the loop takes it back from the
    C part between two polls), writes, reads back and gives it back; the
    polls go on, carried again. Twenty times: the loop lent the connection at
    a poll's end before it dropped that poll's replies, looked at in the
    socket, and the drop could take the borrower's reply (a write that
    timed out)."""
    (tmp_path / "wr.toml").write_text(WRITABLE)
    with SimulatorProcess(["--map", str(tmp_path / "wr.toml"), "wr:1,dynamic=0",
                           "--tcp", "127.0.0.1:0"], quiet=True) as sim:
        (tmp_path / "log.toml").write_text(
            f'maps = ["wr.toml"]\n[[bus]]\ntcp = "{sim.endpoint}"\ninterval = 0\n'
            'timeout = 5\npipeline = 2\n[[bus.device]]\ntype = "wr"\naddress = 1\n')
        out: queue.Queue[list[Sample | Event | PollBlock]] = queue.Queue()
        stop = threading.Event()
        loop = TcpMapPoller(list(load_config(tmp_path / "log.toml").buses), out, stop, Stats())
        loop.start()

        def carried(within: float) -> bool:
            """Whether a block of carried polls is handed over within ``within`` seconds."""
            deadline = time.monotonic() + within
            while time.monotonic() < deadline:
                with contextlib.suppress(queue.Empty):
                    if any(isinstance(i, PollBlock) for i in out.get(timeout=0.1)):
                        return True
            return False
        try:
            assert carried(5.0)  # the C part carries the polls
            (target,) = write_targets([loop], WriteBudget()).values()
            for value in range(10, 30):  # (the lending raced the poll's end: often)
                t0 = time.monotonic()
                try:
                    dev = target.device()
                    assert dev is not None
                    dev.write("setpoint", value)
                    assert dev.read("setpoint") == {"setpoint": value}
                finally:
                    target.release()
                assert time.monotonic() - t0 < 4.0  # lent at once, not near the 5 s poll timeout
                assert carried(5.0)  # carried again
        finally:
            stop.set()
            loop.join(10)
    assert not loop.is_alive()


LATE_MAP = '''schema = "pymb.map/1"
[device]
id = "wr"
table = "holding"
[[point]]
name = "a"
address = 0
type = "u16"
[[point]]
name = "setpoint"
address = 1
type = "u16"
access = "rw"
'''


def test_a_late_poll_reply_is_not_a_write_commands_answer(tmp_path: Path) -> None:
    """A gateway answers the first poll of a connection after its 0.2 s
    timeout (registers 11), every request after it at once (registers 22).
    A write command borrows the connection as soon as the poll timed out:
    its read is answered by its own reply, not by the poll's late one; the
    polls and the command's requests never share a transaction id on the
    connection (a late reply would be taken for the other's answer)."""
    tids: list[int] = []

    def script(n: int, req: Request, conn: socket.socket) -> bytes:
        tid, unit, fc, address, count = req
        tids.append(tid)
        if n == 1:
            time.sleep(0.35)
            return mbap(tid, unit, bytes((fc,)) + registers([11] * count))
        if fc == 6:
            return mbap(tid, unit, struct.pack(">BHH", 6, address, count))
        return mbap(tid, unit, bytes((fc,)) + registers([22] * count))

    gw = Hostile(script)
    (tmp_path / "wr.toml").write_text(LATE_MAP)
    (tmp_path / "log.toml").write_text(
        f'maps = ["wr.toml"]\n[[bus]]\ntcp = "127.0.0.1:{gw.port}"\ninterval = 0.3\n'
        'timeout = 0.2\n[[bus.device]]\ntype = "wr"\naddress = 1\n')
    out: queue.Queue[list[Sample | Event | PollBlock]] = queue.Queue()
    stop = threading.Event()
    loop = TcpMapPoller(list(load_config(tmp_path / "log.toml").buses), out, stop, Stats())
    loop.start()
    try:
        events: list[Event] = []
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and "timeout" not in {e.kind for e in events}:
            with contextlib.suppress(queue.Empty):
                events += [i for i in out.get(timeout=0.05) if isinstance(i, Event)]
        assert "timeout" in {e.kind for e in events}, events
        target = next(iter(write_targets([loop], WriteBudget()).values()))
        for _ in range(4):  # polls go on between the loans
            dev = target.device()
            assert dev is not None
            try:
                assert dev.read() == {"a": 22, "setpoint": 22}
            finally:
                target.release()
            time.sleep(0.4)
    finally:
        stop.set()
        loop.join(10)
        gw.close()
    assert not loop.is_alive()
    assert len(gw.accepted) == 1
    assert len(tids) >= 8, tids  # 4 reads, and the polls between them
    assert len(set(tids)) == len(tids), tids
