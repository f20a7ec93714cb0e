"""The bench's bare loop over many Modbus TCP devices (pymb.bench.fanout): every
device on its own port of one ``pymb simulate --tcp ... --count N`` process;
at a 1 s interval no slot is missed, every poll is one stored sample whose
registers decode to the device's values; a poll that overruns its slots
misses them, and every slot is polled or missed (the one schedule's slots);
a silent device costs its own timeouts only; exceptions and refused
connections are counted per device, on slots and flat out; flat out, the C
loop carries the polls whose requests all fit the pipeline, and only those."""

from __future__ import annotations

import socket
import struct
import threading
import time
from pathlib import Path

import pytest

from pymb.bench.fanout import FanoutDevice, Sample, TcpFanout
from pymb.bench.gatebench import TEN_POINTS
from pymb.maps import Decoder, load
from pymb.sim import SimulatorProcess

TEN = TEN_POINTS  # the 10-point device the gateway bench polls
READ = (("input", 0, 20),)  # the ten points, one request


def _poll(tmp_path: Path, devices: int, seconds: float) -> None:
    path = tmp_path / "ten.toml"
    path.write_text(TEN)
    m = load(str(path))
    samples: list[Sample] = []
    with SimulatorProcess(["--map", str(path), "ten-floats:1,dynamic=0", "--tcp",
                           "127.0.0.1:0", "--count", str(devices)], quiet=True) as sim:
        ports = sim.tcp_ports
        assert len(ports) == devices
        f = TcpFanout([FanoutDevice("127.0.0.1", p, 1, READ) for p in ports], samples.extend,
                      interval=1.0, timeout=0.5)
        stats = f.run(seconds)
    assert stats.missed == [0] * devices
    assert stats.timeouts == [0] * devices
    assert stats.errors == [0] * devices
    assert stats.exceptions == [0] * devices
    polls = int(seconds)
    assert all(polls - 1 <= n <= polls + 1 for n in stats.polls), stats.polls
    assert len(samples) == sum(stats.polls)
    assert stats.carried == 0  # polls on slots are this loop's, not the C loop's
    assert {i for _, i, _ in samples} == set(range(devices))
    decoder = Decoder(m)
    want = [i + 0.5 for i in range(10)]
    for _, _, image in samples[:: max(1, len(samples) // 50)]:
        b = decoder.decode(list(struct.unpack(">20H", image)))
        assert list(b.values[:10]) == want


def test_twenty_devices_for_ten_seconds_miss_no_slot(tmp_path: Path) -> None:
    _poll(tmp_path, 20, 10.0)


def test_a_poll_that_overruns_its_slot_misses_the_slots_it_overran(tmp_path: Path) -> None:
    # 0.2 s slots, replies 0.3 s late: a poll at slot k ends after slot k + 1
    # began, so that one is missed and the next poll waits for slot k + 2
    path = tmp_path / "ten.toml"
    path.write_text(TEN)
    with SimulatorProcess(["--map", str(path), "ten-floats:1,dynamic=0", "--tcp",
                           "127.0.0.1:0", "--fault", "late,delay=0.3"], quiet=True) as sim:
        f = TcpFanout([FanoutDevice("127.0.0.1", sim.tcp_ports[0], 1, READ)], lambda _: None,
                      interval=0.2, timeout=5.0)
        stats = f.run(3.0)
    polls, missed = stats.polls[0], stats.missed[0]
    assert stats.timeouts == [0]
    assert stats.errors == [0]
    assert polls >= 3, (polls, missed)
    assert missed >= polls - 1, (polls, missed)
    # drift-free: each slot of the (under 3 s) run was polled or missed, the
    # one in flight at the end aside; none crammed in
    assert 10 <= polls + missed <= 15, (polls, missed)


def _silent_server() -> tuple[socket.socket, threading.Event]:
    """A TCP server that accepts and never answers (a hung device)."""
    srv = socket.create_server(("127.0.0.1", 0))
    done = threading.Event()
    held: list[socket.socket] = []

    def serve() -> None:
        srv.settimeout(0.1)
        while not done.is_set():
            try:
                held.append(srv.accept()[0])
            except TimeoutError:
                continue
        for s in held:
            s.close()
        srv.close()

    threading.Thread(target=serve, daemon=True).start()
    return srv, done


@pytest.mark.parametrize("interval", [0.5, 0.0])
def test_a_silent_device_costs_its_own_timeouts_only(tmp_path: Path, interval: float) -> None:
    # flat out (0), the C loop carries the live devices' polls and hands the
    # others back: a silent poll at its deadline, a refused one as it comes
    path = tmp_path / "ten.toml"
    path.write_text(TEN)
    srv, done = _silent_server()
    free = socket.create_server(("127.0.0.1", 0))
    refused = free.getsockname()[1]
    free.close()  # nothing listens there now
    samples: list[Sample] = []
    try:
        with SimulatorProcess(["--map", str(path), "ten-floats:1,dynamic=0", "--tcp",
                               "127.0.0.1:0", "--count", "3"], quiet=True) as sim:
            live = [FanoutDevice("127.0.0.1", p, 1, READ) for p in sim.tcp_ports]
            bad = FanoutDevice("127.0.0.1", sim.tcp_ports[0], 1, (("input", 100, 2),))
            devices = [*live, FanoutDevice("127.0.0.1", srv.getsockname()[1], 1, READ), bad,
                       FanoutDevice("127.0.0.1", refused, 1, READ)]
            f = TcpFanout(devices, samples.extend, interval=interval, timeout=0.2, retry=0.5)
            stats = f.run(4.0)
    finally:
        done.set()
    if interval:
        assert stats.missed[:3] == [0, 0, 0]
        assert stats.carried == 0
    else:  # no slots to miss; the live devices' polls the C loop's but their first
        assert stats.missed == [0] * 6
        assert stats.carried > sum(stats.polls) // 2
    assert min(stats.polls[:3]) >= 7
    assert stats.timeouts[3] >= 2  # the silent one: a timeout, a new connection, again
    assert stats.polls[3] == 0
    assert stats.exceptions[4] >= 7  # exception 02: an address the map does not have
    assert stats.polls[4] == 0
    assert stats.errors[5] >= 2  # refused, retried
    assert {i for _, i, _ in samples} == {0, 1, 2}


@pytest.mark.parametrize("pipeline", [5, 1])
def test_flat_out_polls_keep_the_requests_in_order(tmp_path: Path, pipeline: int) -> None:
    path = tmp_path / "ten.toml"
    path.write_text(TEN)
    m = load(str(path))
    # the ten points as five requests, all in flight at once (the C loop's
    # polls), or one at a time (this loop's), answered in order
    reads = tuple(("input", a, 4) for a in range(0, 20, 4))
    samples: list[Sample] = []
    with SimulatorProcess(["--map", str(path), "ten-floats:1,dynamic=0", "--tcp",
                           "127.0.0.1:0", "--count", "4"], quiet=True) as sim:
        devices = [FanoutDevice("127.0.0.1", p, 1, reads) for p in sim.tcp_ports]
        f = TcpFanout(devices, samples.extend, interval=0, pipeline=pipeline, timeout=2.0)
        timer = threading.Timer(1.5, f.stop)
        timer.start()
        t0 = time.time_ns()
        stats = f.run(30.0)
        t1 = time.time_ns()
        timer.cancel()
    assert min(stats.polls) > 10
    assert stats.errors == [0] * 4
    assert stats.timeouts == [0] * 4
    assert len(samples) == sum(stats.polls)
    if pipeline == 5:  # each connection's first poll is this loop's, the C loop's from then on
        assert stats.carried > sum(stats.polls) // 2
    else:
        assert stats.carried == 0
    for d in range(4):  # each sample's time: its poll's start, on the wall clock
        starts = [t for t, i, _ in samples if i == d]
        assert starts == sorted(starts)
        assert t0 <= starts[0]
        assert starts[-1] <= t1
        assert len(set(starts)) == len(starts)
    decoder = Decoder(m)
    for _, _, image in samples[:: max(1, len(samples) // 50)]:
        assert list(decoder.decode(list(struct.unpack(">20H", image))).values[:10]) == [
            i + 0.5 for i in range(10)]


def test_mistakes_are_invalid_arguments() -> None:
    from pymb.errors import InvalidArgument
    with pytest.raises(InvalidArgument, match="unknown table"):
        FanoutDevice("127.0.0.1", 502, 1, (("inputs", 0, 2),))
    with pytest.raises(InvalidArgument, match="not one read"):
        FanoutDevice("127.0.0.1", 502, 1, (("input", 0, 126),))
    with pytest.raises(InvalidArgument, match="a poll needs a request"):
        FanoutDevice("127.0.0.1", 502, 1, ())
    with pytest.raises(InvalidArgument, match="pipeline"):
        TcpFanout([FanoutDevice("127.0.0.1", 502, 1, READ)], print, pipeline=0)
    with pytest.raises(InvalidArgument, match="no devices"):
        TcpFanout([], print)
