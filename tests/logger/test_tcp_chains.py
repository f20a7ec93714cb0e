"""The polls of several devices behind one TCP connection that fall due
together, carried one after another by the loop's C part (a chain,
:meth:`pymb.logger.tcpbase.TcpLoopBase.chain`): the same samples and events
as the loop's own polls give, a device that falls silent or refuses a point
in the middle of a chain, and a write command lent the connection while
chains run."""

from __future__ import annotations

import contextlib
import itertools
import queue
import socket
import sqlite3
import struct
import threading
import time
from pathlib import Path

from conftest import run_pymb
from hostile_gateway import HX_MAP, Handed, Hostile, Request, Script, good, poll

from pymb.devices.mapwrite import WriteBudget
from pymb.logger.config import load_config
from pymb.logger.stats import Stats
from pymb.logger.targets import write_targets
from pymb.logger.tcploop import TcpMapPoller
from pymb.sim import SimulatorProcess
from pymb.store import Event, Sample
from pymb.store.block import PollBlock

#: two more points, too far apart to be read in one request: a poll of 3
#: requests (addresses 0, 300 and 600), sent 2 at a time
FAR = "".join(f'[[point]]\nname = "p{a}"\naddress = {a}\ntype = "u16"\n' for a in (300, 600))
UNITS = (1, 2, 3)
AT_RATE = "timeout = 0.5\ninterval = 0.2\npipeline = 2\n"
#: events of a run with no fault (a slot that a slow poll overran is skipped, said so)
QUIET = {"connect", "skipped"}


def _want(unit: int) -> dict[str, int]:
    """The values of ``unit``'s points (the gateway's rule: 100 x unit + address)."""
    return {"a": 100 * unit, "b": 100 * unit + 1, "p300": 100 * unit + 300,
            "p600": 100 * unit + 600}


def _poll(tmp_path: Path, script: Script, until: int, units: tuple[int, ...] = UNITS,
          within: float = 20.0) -> Handed:
    gw = Hostile(script)
    try:
        return poll(tmp_path, [gw.port], lambda h: len(h.samples) >= until, units=units,
                    bus=AT_RATE, points=FAR, within=within)
    finally:
        gw.close()


def _by_unit(got: Handed) -> dict[int, list[Sample]]:
    out: dict[int, list[Sample]] = {}
    for s in got.samples:
        out.setdefault(s.device.address, []).append(s)
    return out


def test_devices_due_together_are_read_one_after_another_as_the_loop_reads_them(
        tmp_path: Path) -> None:
    """Three devices behind one gateway, every 0.2 s, polls of three requests
    two at a time: the C part carries them (blocks), and each device's samples
    hold what a poll the loop reads itself holds (one device alone on its
    connection: no chain), one a slot, each stamped in order."""
    got = _poll(tmp_path, lambda n, req, conn: good(*req), 30)
    assert got.kinds()[0] == "connect"
    assert set(got.kinds()) <= QUIET
    assert got.blocks
    alone = _poll(tmp_path, lambda n, req, conn: good(*req), 10, units=(2,))
    assert alone.kinds()[0] == "connect"
    assert set(alone.kinds()) <= QUIET
    assert not alone.blocks
    mine = [s for s in got.samples if s.device.address == 2]
    for s, t in zip(mine, alone.samples, strict=False):
        assert s.data.values == t.data.values == _want(2)  # type: ignore[union-attr]
        assert s.data.unsupported == t.data.unsupported == ()  # type: ignore[union-attr]
        assert (s.device.name, s.device.address) == (t.device.name, t.device.address)
    for unit, samples in _by_unit(got).items():
        assert {tuple(sorted(s.data.values.items())) for s in samples} == {  # type: ignore[union-attr]
            tuple(sorted(_want(unit).items()))}
        times = [s.monotonic for s in samples]
        assert times == sorted(times)
        gaps = [b - a for a, b in itertools.pairwise(times)]
        assert min(gaps) > 0.1  # one poll a slot of 0.2 s at most
    assert {len(v) for v in _by_unit(got).values()} <= {9, 10, 11, 12}


def _unit_quiet_after(unit: int, k: int) -> Script:
    """Every request answered right, but ``unit``'s from its ``k``-th on: none."""
    seen = [0]

    def script(n: int, req: Request, conn: socket.socket) -> bytes | None:
        if req[1] == unit:
            seen[0] += 1
            if seen[0] >= k:
                return None
        return good(*req)
    return script


def test_a_device_silent_in_the_middle_of_a_chain_times_out_by_name(tmp_path: Path) -> None:
    """Device 2 of three answers no more from its 10th request on: its poll
    times out at the 0.5 s timeout, named as any timeout is; devices 1 and 3
    go on storing their polls after it."""
    got = _poll(tmp_path, _unit_quiet_after(2, 10), 1000, within=3.0)
    timeouts = [e for e in got.events if e.kind == "timeout"]
    assert timeouts, got.kinds()
    assert got.blocks
    assert all("read_holding_registers(slave=2" in e.message for e in timeouts)
    first = timeouts[0].monotonic
    later = {s.device.address for s in got.samples if s.monotonic > first + 0.2}
    assert later == {1, 3}
    assert {s.device.address for s in got.samples if s.monotonic < first} == {1, 2, 3}
    for unit, samples in _by_unit(got).items():
        assert all(s.data.values == _want(unit) for s in samples)  # type: ignore[union-attr]


def _unit_refuses_300(unit: int, k: int) -> Script:
    """Every request answered right, but ``unit``'s for register 300 from
    its ``k``-th on: exception 02 (a point it does not have)."""
    seen = [0]

    def script(n: int, req: Request, conn: socket.socket) -> bytes | None:
        tid, u, fc, address, _ = req
        if u == unit and address == 300:
            seen[0] += 1
            if seen[0] >= k:
                return tid.to_bytes(2, "big") + b"\x00\x00\x00\x03" + bytes((u, fc | 0x80, 2))
        return good(*req)
    return script


def test_a_point_refused_in_the_middle_of_a_chain_is_replanned_in_that_poll(
        tmp_path: Path) -> None:
    """Device 2 of three refuses register 300 (exception 02) from its 5th
    poll on: that poll's sample already reads the point ``unsupported``, and
    so do its later ones (carried again); devices 1 and 3 read it; nothing fails."""
    got = _poll(tmp_path, _unit_refuses_300(2, 5), 45)
    assert set(got.kinds()) <= QUIET
    assert got.blocks
    by = _by_unit(got)
    gone = [s.data.unsupported for s in by[2]]  # type: ignore[union-attr]
    assert gone == [()] * 4 + [("p300",)] * (len(gone) - 4)
    assert all(s.data.unsupported == () for u in (1, 3) for s in by[u])  # type: ignore[union-attr]
    assert got.stats.unsupported.get("hx-2") == {"p300"}


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


def test_a_write_reaches_a_device_of_a_chain_between_two_polls(tmp_path: Path) -> None:
    """Three devices behind one simulator port every 0.05 s, their polls
    carried in chains; a write command to device 2 borrows the connection
    (the loop takes it back from the C part, lends it between two polls),
    writes, reads back and gives it back; the chains go on. Ten times."""
    (tmp_path / "wr.toml").write_text(WRITABLE)
    with SimulatorProcess(["--map", str(tmp_path / "wr.toml"),
                           *(f"wr:{u},dynamic=0" for u in UNITS), "--tcp", "127.0.0.1:0"],
                          quiet=True) as sim:
        (tmp_path / "log.toml").write_text(
            f'maps = ["wr.toml"]\n[[bus]]\ntcp = "{sim.endpoint}"\ninterval = 0.05\n'
            'timeout = 5\npipeline = 1\n' + "".join(
                f'[[bus.device]]\ntype = "wr"\naddress = {u}\n' for u in UNITS))
        out: queue.Queue[list[Sample | Event | PollBlock]] = queue.Queue()
        stop = threading.Event()
        loop = TcpMapPoller(list(load_config(tmp_path / "log.toml").buses), out, stop, Stats())
        loop.start()
        events: list[Event] = []

        def carried(within: float) -> bool:
            """Whether a block of carried polls is handed over within ``within`` seconds."""
            deadline = time.monotonic() + within
            while time.monotonic() < deadline:
                with contextlib.suppress(queue.Empty):
                    items = out.get(timeout=0.1)
                    events.extend(i for i in items if isinstance(i, Event))
                    if any(isinstance(i, PollBlock) for i in items):
                        return True
            return False
        try:
            assert carried(5.0)  # the C part carries the chains
            targets = write_targets([loop], WriteBudget())
            target = next(t for name, t in targets.items() if name.endswith("2"))
            for value in range(10, 20):
                t0 = time.monotonic()
                try:
                    dev = target.device()
                    assert dev is not None
                    dev.write("setpoint", value)
                    assert dev.read("setpoint") == {"setpoint": value}
                finally:
                    target.release()
                assert time.monotonic() - t0 < 4.0  # lent between two polls
                assert carried(5.0)  # carried again
        finally:
            stop.set()
            loop.join(10)
    assert not loop.is_alive()
    assert {e.kind for e in events} <= {"connect", "skipped"}


def _unit_2_lies() -> Script:
    """Right replies, but every 7th request of unit 2 answered by unit 9
    (another unit id, registers of its own) and every 11th with exception 04."""
    seen = [0]

    def script(n: int, req: Request, conn: socket.socket) -> bytes | None:
        tid, unit, fc, address, count = req
        if unit != 2:
            return good(*req)
        seen[0] += 1
        if seen[0] % 7 == 0:
            return good(tid, 9, fc, address, count)
        if seen[0] % 11 == 0:
            return tid.to_bytes(2, "big") + b"\x00\x00\x00\x03" + bytes((unit, fc | 0x80, 4))
        return good(*req)
    return script


def test_pymb_log_stores_a_chain_beside_a_device_that_lies(tmp_path: Path) -> None:
    """``pymb log`` reads three devices behind one gateway in chains; the
    gateway lies for device 2 (replies of another unit, exception 04). In the
    file: every sample of each device holds its own registers, each fault is
    an event of device 2 alone, and devices 1 and 3 are read all along."""
    (tmp_path / "hx.toml").write_text(HX_MAP + FAR)
    gw = Hostile(_unit_2_lies())
    (tmp_path / "log.toml").write_text(
        f'maps = ["hx.toml"]\n[[bus]]\nname = "gw"\ntcp = "127.0.0.1:{gw.port}"\n{AT_RATE}'
        + "".join(f'[[bus.device]]\ntype = "hx"\nname = "u{u}"\naddress = {u}\n'
                  for u in UNITS))
    db = tmp_path / "data.sqlite"
    try:
        r = run_pymb("log", "--config", str(tmp_path / "log.toml"), "--seconds", "4",
                     "--out", str(db), "--quiet", timeout=60)
    finally:
        gw.close()
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    con = sqlite3.connect(db)
    try:
        rows = con.execute("SELECT d.address, s.registers, count(*), min(s.monotonic),"
                           " max(s.monotonic) FROM samples s JOIN devices d"
                           " ON d.id = s.device_id GROUP BY d.address, s.registers").fetchall()
        faults = con.execute("SELECT d.address, e.kind FROM events e LEFT JOIN devices d"
                             " ON d.id = e.device_id WHERE e.kind NOT IN"
                             " ('connect', 'reconnect', 'skipped', 'offline', 'online')"
                             ).fetchall()
        span = con.execute("SELECT min(monotonic), max(monotonic) FROM samples").fetchone()
    finally:
        con.close()
    assert sorted(u for u, *_ in rows) == [1, 2, 3]  # one set of registers each
    for unit, blob, n, first, last in rows:
        regs = struct.unpack(f">{len(blob) // 2}H", blob)
        want = {a: 100 * unit + a for a in (0, 1, 300, 600)}
        assert {a: regs[a] for a in want} == want, unit
        if unit != 2:  # read all along
            assert n >= 10, (unit, n)
            assert first - span[0] < 1.0, (unit, first, span)
            assert span[1] - last < 1.0, (unit, last, span)
    kinds = {k for _, k in faults}
    assert kinds == {"protocol", "exception"}, faults
    assert {u for u, _ in faults} == {2}, faults
