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
import struct
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from conftest import run_pymb

from pymb.devices.mapreading import MapReading
from pymb.devices.spec import DeviceConfig
from pymb.logger import BusConfig, LogConfig, Logger
from pymb.logger.config import load_config
from pymb.logger.poller import BusPoller, Stats
from pymb.logger.tcploop import TcpMapPoller, fans_out
from pymb.sim import SimulatorProcess
from pymb.store import Event, Sample, SqliteSink, samples_after

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


def _collect(make: Callable[[queue.Queue[list[Sample | Event]], threading.Event, Stats],
                            threading.Thread], want: set[tuple[str, str | None]]) -> Collected:
    """Samples by (device, group) until each has 3 (or 1 for the once
    group), within 30 s."""
    q: queue.Queue[list[Sample | Event]] = queue.Queue()
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
            for s in items:
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


LATE_MAP = '''schema = "pymb.map/1"
[device]
id = "late-test"
table = "holding"
[device.timing]
offline_after = 1
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


class _Gateway:
    """A scripted Modbus TCP gateway (not pymb's simulator): registers
    ``100 x unit + address``; unit 2 answers 0.3 s late (after the loop's
    0.2 s timeout, while unit 1's request waits behind it); counts the
    connections it accepts. Requests are answered in order."""

    def __init__(self) -> None:
        self.server = socket.create_server(("127.0.0.1", 0))
        self.port = self.server.getsockname()[1]
        self.accepted = 0
        self.open: list[socket.socket] = []
        self.done = threading.Event()
        self.thread = threading.Thread(target=self._accept, daemon=True)
        self.thread.start()

    def _accept(self) -> None:
        self.server.settimeout(0.1)
        while not self.done.is_set():
            try:
                conn, _ = self.server.accept()
            except TimeoutError:
                continue
            self.accepted += 1
            self.open.append(conn)
            threading.Thread(target=self._serve, args=(conn,), daemon=True).start()

    def _serve(self, conn: socket.socket) -> None:
        buf = b""
        with conn:
            conn.settimeout(0.1)
            while not self.done.is_set():
                try:
                    data = conn.recv(4096)
                except TimeoutError:
                    continue
                except OSError:  # the poller closed its end at stop
                    return
                if not data:
                    return
                buf += data
                while len(buf) >= 12:
                    tid, _, _, unit, fc, address, count = struct.unpack(">HHHBBHH", buf[:12])
                    buf = buf[12:]
                    if unit == 2:
                        time.sleep(0.3)
                    regs = [100 * unit + address + i for i in range(count)]
                    pdu = struct.pack(f">BB{count}H", fc, 2 * count, *regs)
                    try:
                        conn.sendall(struct.pack(">HHHB", tid, 0, len(pdu) + 1, unit) + pdu)
                    except OSError:  # the poller closed its end at stop
                        return

    def drop(self) -> None:
        """Close every connection (the gateway restarted)."""
        for conn in self.open:
            conn.shutdown(socket.SHUT_RDWR)
        self.open.clear()

    def close(self) -> None:
        self.done.set()
        self.thread.join(5.0)
        self.server.close()


def test_a_late_reply_is_skipped_and_the_gateway_keeps_one_connection(tmp_path: Path
                                                                      ) -> None:
    (tmp_path / "late.toml").write_text(LATE_MAP)
    gw = _Gateway()
    try:
        (tmp_path / "log.toml").write_text(f'''maps = ["late.toml"]
[[bus]]
tcp = "127.0.0.1:{gw.port}"
timeout = 0.2
[[bus.device]]
type = "late-test"
address = 1
[[bus.device]]
type = "late-test"
address = 2
''')
        bus = load_config(tmp_path / "log.toml").buses[0]
        q: queue.Queue[list[Sample | Event]] = queue.Queue()
        stop = threading.Event()
        poller = TcpMapPoller([bus], q, stop, Stats())
        poller.start()
        samples: list[Sample] = []
        events: list[Event] = []
        deadline = time.monotonic() + 20.0
        try:
            while time.monotonic() < deadline:
                try:
                    items = q.get(timeout=0.5)
                except queue.Empty:
                    continue
                samples += [s for s in items if isinstance(s, Sample)]
                events += [e for e in items if isinstance(e, Event)]
                late = [e for e in events if e.kind == "timeout"]
                if len(late) >= 3 and len(samples) >= 50:
                    break
        finally:
            stop.set()
            poller.join(5.0)
    finally:
        gw.close()
    assert len([e for e in events if e.kind == "timeout"]) >= 3
    assert all(e.device is not None and e.device.address == 2
               for e in events if e.kind == "timeout")
    assert [e.kind for e in events if e.kind not in ("timeout", "connect")] == []
    assert gw.accepted == 1  # one connection for both units, kept through the timeouts
    assert len(samples) >= 50
    # every sample holds its own unit's registers: no late reply taken for another's
    assert {(s.device.address, tuple(_map(s).values.values())) for s in samples} == {
        (1, (100, 101))}


def test_slots_a_slow_unit_overran_are_skipped_and_counted(tmp_path: Path) -> None:
    """Unit 2 answers in 0.3 s, the bus's interval is 0.1 s: its slots that
    a poll overran are skipped, counted and recorded as ``skipped`` events
    naming it; unit 1 behind the same gateway waits its turn."""
    (tmp_path / "late.toml").write_text(LATE_MAP)
    gw = _Gateway()
    try:
        (tmp_path / "log.toml").write_text(f'''maps = ["late.toml"]
[[bus]]
tcp = "127.0.0.1:{gw.port}"
timeout = 1
interval = 0.1
[[bus.device]]
type = "late-test"
address = 1
[[bus.device]]
type = "late-test"
address = 2
''')
        bus = load_config(tmp_path / "log.toml").buses[0]
        q: queue.Queue[list[Sample | Event]] = queue.Queue()
        stop = threading.Event()
        stats = Stats()
        poller = TcpMapPoller([bus], q, stop, stats)
        poller.start()
        events: list[Event] = []
        samples: list[Sample] = []
        deadline = time.monotonic() + 20.0
        try:
            while time.monotonic() < deadline and len(
                    [e for e in events if e.kind == "skipped"]) < 3:
                try:
                    items = q.get(timeout=0.5)
                except queue.Empty:
                    continue
                events += [e for e in items if isinstance(e, Event)]
                samples += [s for s in items if isinstance(s, Sample)]
        finally:
            stop.set()
            poller.join(5.0)
    finally:
        gw.close()
    skipped = [e for e in events if e.kind == "skipped"]
    assert len(skipped) >= 3
    assert stats.skipped_slots >= len(skipped)
    assert any("late-test-2" in e.message for e in skipped)
    assert "timeout" not in {e.kind for e in events}
    assert {s.device.address for s in samples} == {1, 2}


def test_a_dropped_connection_is_reopened_with_events(tmp_path: Path) -> None:
    """The gateway closes the connection: the device being polled gets a
    ``connection`` event, the bus is opened again (``reconnect``) and its
    devices are polled on the new connection."""
    (tmp_path / "late.toml").write_text(LATE_MAP)
    gw = _Gateway()
    try:
        (tmp_path / "log.toml").write_text(f'''maps = ["late.toml"]
[[bus]]
tcp = "127.0.0.1:{gw.port}"
[[bus.device]]
type = "late-test"
address = 1
''')
        bus = load_config(tmp_path / "log.toml").buses[0]
        q: queue.Queue[list[Sample | Event]] = queue.Queue()
        stop = threading.Event()
        poller = TcpMapPoller([bus], q, stop, Stats())
        poller.start()
        kinds: list[str] = []
        after = 0  # samples after the reconnect
        deadline = time.monotonic() + 20.0
        try:
            while time.monotonic() < deadline and after < 20:
                try:
                    items = q.get(timeout=0.5)
                except queue.Empty:
                    continue
                for item in items:
                    if isinstance(item, Event):
                        kinds.append(item.kind)
                    elif "reconnect" in kinds:
                        after += 1
                    elif len(kinds) == 1 and gw.open:  # connected and polling: drop it
                        gw.drop()
        finally:
            stop.set()
            poller.join(5.0)
    finally:
        gw.close()
    assert kinds[:3] == ["connect", "connection", "reconnect"], kinds
    assert after >= 20
    assert gw.accepted == 2
