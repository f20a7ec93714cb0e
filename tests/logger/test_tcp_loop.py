"""The one loop that polls every map device on Modbus TCP
(:mod:`pymb.logger.tcploop`) against a thread per bus
(:class:`~pymb.logger.poller.BusPoller`), on the same simulated devices:
the samples they hand the writer store the same registers, the same
``unsupported`` marks and decode to the same values, group by group, with
a bridge the device refuses (re-planned within the poll), a point it
refuses alone (``unsupported``), a block, coils and three group intervals
(one of them 0: once a connection)."""

from __future__ import annotations

import queue
import socket
import sqlite3
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from conftest import run_pymb
from hostile_gateway import Hostile, Request, good, poll

from pymb.devices.mapreading import MapReading
from pymb.logger import BusConfig, DeviceConfig, LogConfig, Logger
from pymb.logger.config import load_config
from pymb.logger.poller import BusPoller, Stats
from pymb.logger.tcploop import TcpMapPoller, fans_out
from pymb.sim import SimulatorProcess
from pymb.store import Event, Sample, SqliteSink, samples_after
from pymb.store.block import PollBlock

SERVED = '''schema = "pymb.map/1"
[device]
id = "mixed"
table = "input"
[[point]]
name = "voltage_v"
address = 0
type = "f32"
example = 230.5
[[point]]
name = "status"
address = 4
type = "u16"
example = 7
[[block]]
name = "temp_c"
table = "holding"
first = 10
count = 4
stride = 1
type = "i16"
scale = 0.1
[[point]]
name = "run"
table = "coil"
address = 0
type = "bool"
example = true
[[point]]
name = "fault"
table = "coil"
address = 3
type = "bool"
'''

#: what the logger is told: the served points in three groups, registers
#: 2..3 bridgeable (the device refuses them) and a point it does not have
LOGGED = SERVED.replace('table = "input"\n', '''table = "input"
[device.limits]
max_gap = 4
readable = { input = [[0, 10]] }
[groups]
fast = { interval = 0.1 }
slow = { interval = 0.3 }
once = { interval = 0 }
''', 1).replace('example = 230.5\n', 'example = 230.5\ngroup = "fast"\n').replace(
    'example = 7\n', 'example = 7\ngroup = "fast"\n').replace(
    'scale = 0.1\n', 'scale = 0.1\ngroup = "slow"\n').replace(
    'example = true\n', 'example = true\ngroup = "slow"\n').replace(
    'address = 3\ntype = "bool"\n', 'address = 3\ntype = "bool"\ngroup = "once"\n') + '''
[[point]]
name = "missing_a"
address = 8
type = "f32"
group = "fast"
'''

Collected = dict[tuple[str, str | None], list[Sample]]


def _map(s: Sample) -> MapReading:
    assert isinstance(s.data, MapReading)
    return s.data


def _collect(make: Callable[[queue.Queue[list[Sample | Event | PollBlock]], threading.Event,
                             Stats], threading.Thread],
             want: set[tuple[str, str | None]]) -> Collected:
    """Samples by (device, group) until each has 3 (or 1 for the once
    group), within 30 s."""
    q: queue.Queue[list[Sample | Event | PollBlock]] = queue.Queue()
    stop = threading.Event()
    got: Collected = {}
    poller = make(q, stop, Stats())
    poller.start()
    deadline = time.monotonic() + 30.0
    try:
        while time.monotonic() < deadline:
            try:
                items = q.get(timeout=0.5)
            except queue.Empty:
                continue
            for s in (s for i in items
                      for s in (i.samples() if isinstance(i, PollBlock) else [i])):
                if isinstance(s, Sample):
                    got.setdefault((s.device.name, _map(s).group), []).append(s)
            if all(len(got.get(k, ())) >= (1 if k[1] == "once" else 3) for k in want):
                break
    finally:
        stop.set()
        poller.join(5.0)
    return got


def _stored(db: Path, samples: list[Sample]) -> dict[tuple[str, str], set[tuple[bytes, int]]]:
    sink = SqliteSink(db)
    sink.write_batch(samples)
    sink.close()
    con = sqlite3.connect(db)
    try:
        out: dict[tuple[str, str], set[tuple[bytes, int]]] = {}
        for name, units, regs, gone in con.execute(
                "SELECT d.name, d.humidity_units, s.registers, s.unsupported FROM samples s "
                "JOIN devices d ON d.id = s.device_id"):
            out.setdefault((name, units), set()).add((regs, gone))
        return out
    finally:
        con.close()


def test_the_loop_stores_what_a_thread_per_bus_stores(tmp_path: Path) -> None:
    (tmp_path / "served.toml").write_text(SERVED)
    (tmp_path / "logged.toml").write_text(LOGGED)
    with SimulatorProcess(["--map", str(tmp_path / "served.toml"), "mixed:1,dynamic=0",
                           "mixed:2,dynamic=0", "--tcp", "127.0.0.1:0"], quiet=True) as sim:
        (tmp_path / "log.toml").write_text(f'''maps = ["logged.toml"]
[[bus]]
name = "gw"
tcp = "{sim.endpoint}"
timeout = 1
[[bus.device]]
type = "mixed"
address = 1
[[bus.device]]
type = "mixed"
address = 2
''')
        bus = load_config(tmp_path / "log.toml").buses[0]
        assert fans_out(bus)
        want: set[tuple[str, str | None]] = {
            (f"mixed-{a}", g) for a in (1, 2) for g in ("fast", "slow", "once")}
        threads = _collect(lambda q, stop, stats: BusPoller(bus, q, stop, stats), want)
        loop = _collect(lambda q, stop, stats: TcpMapPoller([bus], q, stop, stats), want)
    assert set(threads) == set(loop) == want
    for key in want:
        a, b = _map(threads[key][-1]), _map(loop[key][-1])
        assert a.registers == b.registers, key
        assert a.unsupported == b.unsupported, key
        assert dict(a.values) == dict(b.values), key
        assert dict(a.states) == dict(b.states), key
    fast = _map(loop[("mixed-1", "fast")][-1])
    assert fast.unsupported == ("missing_a",)
    assert fast.values["voltage_v"] == 230.5
    assert _map(loop[("mixed-1", "slow")][-1]).values["run"] is True
    rows_threads = _stored(tmp_path / "threads.sqlite", [s for v in threads.values() for s in v])
    rows_loop = _stored(tmp_path / "loop.sqlite", [s for v in loop.values() for s in v])
    assert rows_threads == rows_loop
    assert all(len(v) == 1 for v in rows_loop.values())  # the device's values do not move
    decoded = {}
    for name in ("threads", "loop"):
        decoded[name] = {(s.device.name, _map(s).group): dict(_map(s).values)
                         for s in samples_after(tmp_path / f"{name}.sqlite", 0, limit=10_000)}
    assert decoded["threads"] == decoded["loop"]
    export = [run_pymb("export", str(tmp_path / f"{n}.sqlite"), "--csv", "-").stdout
              for n in ("threads", "loop")]
    assert export[0].split("\n", 1)[1].count("230.5") > 0
    # the same values, the same columns (times aside)
    strip = [sorted(",".join(r.split(",")[2:]) for r in e.splitlines()[1:]) for e in export]
    assert set(strip[0]) == set(strip[1])


def test_one_loop_for_every_tcp_bus_a_thread_for_the_others(tmp_path: Path) -> None:
    """Every TCP bus of map devices goes to the one loop; a bus with a
    facade (and serial lines, RTU over TCP) keeps a thread of its own."""
    coolpro = BusConfig("c", tcp="127.0.0.1:1", devices=[DeviceConfig("coolpro", 40)])
    assert not fans_out(coolpro)
    (tmp_path / "log.toml").write_text("".join(
        f'[[bus]]\nname = "m{i}"\ntcp = "127.0.0.1:{1000 + i}"\n'
        f'[[bus.device]]\ntype = "eastron-sdm120"\n' for i in range(3)) +
        '[[bus]]\nname = "r"\nrtu_over_tcp = "127.0.0.1:999"\n'
        '[[bus.device]]\ntype = "eastron-sdm120"\n')
    buses = load_config(tmp_path / "log.toml").buses
    assert [fans_out(b) for b in buses] == [True, True, True, False]
    logger = Logger(LogConfig([coolpro, *buses], path=str(tmp_path / "x.sqlite")))
    loops = [p for p in logger.pollers if isinstance(p, TcpMapPoller)]
    assert len(loops) == 1
    assert loops[0].bus_names == ["m0", "m1", "m2"]
    assert len(logger.pollers) == 3  # the CoolPro's bus, the RTU-over-TCP bus, the loop
    logger.sink.close()


@pytest.mark.parametrize(("pipeline", "says"), [
    ("0", "pipeline must be 1..16 requests, got 0"),
    ('"4"', "pipeline has the wrong type"),
])
def test_pipeline_mistakes(tmp_path: Path, pipeline: str, says: str) -> None:
    config = tmp_path / "bad.toml"
    config.write_text(f'[[bus]]\ntcp = "127.0.0.1:1"\npipeline = {pipeline}\n'
                      '[[bus.device]]\ntype = "eastron-sdm120"\n')
    r = run_pymb("log", "--config", str(config), "--seconds", "1")
    assert r.returncode == 2, r.stderr
    assert says in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def _late_unit_2(n: int, req: Request, conn: socket.socket) -> bytes:
    """Registers ``100 x unit + address``; unit 2 answers 0.3 s late."""
    if req[1] == 2:
        time.sleep(0.3)
    return good(*req)


def test_a_late_reply_is_skipped_and_the_gateway_keeps_one_connection(tmp_path: Path
                                                                      ) -> None:
    """Unit 2 answers after the 0.2 s timeout while unit 1's request waits
    behind it on the one connection: its late replies are skipped by their
    transaction id, never taken for unit 1's."""
    gw = Hostile(_late_unit_2)
    try:
        got = poll(tmp_path, [gw.port], lambda h: h.kinds().count("timeout") >= 3
                   and len(h.samples) >= 50, units=(1, 2), bus="timeout = 0.2\n")
    finally:
        gw.close()
    timeouts = [e for e in got.events if e.kind == "timeout"]
    assert len(timeouts) >= 3
    assert all(e.device is not None and e.device.address == 2 for e in timeouts)
    assert [k for k in got.kinds() if k not in ("timeout", "connect")] == []
    assert len(gw.accepted) == 1  # one connection for both units, kept through the timeouts
    assert len(got.samples) >= 50
    # every sample holds its own unit's registers: no late reply taken for another's
    assert got.values() == {(1, (100, 101))}


def test_slots_a_slow_unit_overran_are_skipped_and_counted(tmp_path: Path) -> None:
    """Unit 2 answers in 0.3 s, the bus's interval is 0.1 s: its slots that
    a poll overran are skipped, counted and recorded as ``skipped`` events
    naming it; unit 1 behind the same gateway waits its turn."""
    gw = Hostile(_late_unit_2)
    try:
        got = poll(tmp_path, [gw.port], lambda h: h.kinds().count("skipped") >= 3,
                   units=(1, 2), bus="timeout = 1\ninterval = 0.1\n")
    finally:
        gw.close()
    skipped = [e for e in got.events if e.kind == "skipped"]
    assert len(skipped) >= 3
    assert got.stats.skipped_slots >= len(skipped)
    assert any("hx-2" in e.message for e in skipped)
    assert "timeout" not in got.kinds()
    assert {s.device.address for s in got.samples} == {1, 2}


def test_a_dropped_connection_is_reopened_with_events(tmp_path: Path) -> None:
    """The gateway closes the connection after four polls: the device being
    polled gets a ``connection`` event, the bus is opened again
    (``reconnect``) and its devices are polled on the new connection."""
    gw: Hostile

    def drop_once(n: int, req: Request, conn: socket.socket) -> bytes | None:
        if len(gw.accepted) == 1 and n == 5:
            conn.shutdown(socket.SHUT_RDWR)
            return None
        return good(*req)

    gw = Hostile(drop_once)
    try:
        got = poll(tmp_path, [gw.port], lambda h: "reconnect" in h.kinds()
                   and len(h.samples) >= 24, bus="")
    finally:
        gw.close()
    assert got.kinds()[:3] == ["connect", "connection", "reconnect"], got.kinds()
    assert len(got.samples) >= 24  # 4 before the drop, 20 on the new connection
    assert len(gw.accepted) == 2
