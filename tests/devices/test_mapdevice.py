"""MapDevice against peers that are not pymb: a scripted responder that has
only some registers and logs every request with its time (RTU on a real
pseudo-terminal, Modbus TCP on 127.0.0.1), and pymodbus's sparse server
(Modbus TCP and RTU over TCP) in its own process."""

from __future__ import annotations

import struct
import time
from itertools import pairwise

import pytest
import reference as ref
from map_peers import Refusing, RefusingPtyPeer, RefusingTcpPeer, sparse_pymodbus
from peerkit import rtu

import pymb
from pymb import maps
from pymb.devices.mapdevice import MapDevice
from pymb.errors import InvalidArgument, ModbusTimeout

HEAD = """schema = "pymb.map/1"
[device]
id = "testdev"
default_address = 1
table = "holding"
"""

POINTS = """
[groups]
fast = { interval = 1.0 }
slow = { interval = 10.0 }

[[point]]
name = "a"
address = 0
type = "u16"
group = "fast"

[[point]]
name = "b"
address = 1
type = "u16"
group = "fast"

[[point]]
name = "c"
address = 3
type = "u32"
group = "fast"

[[point]]
name = "d"
address = 10
type = "i16"
group = "fast"

[[point]]
name = "e"
address = 20
type = "u16"
group = "slow"

[[point]]
name = "f"
address = 21
type = "u16"
group = "slow"

[[point]]
name = "g"
address = 22
type = "u16"
group = "slow"

[[point]]
name = "h"
address = 23
type = "u16"
group = "slow"
"""

#: What the scripted peer has: g (22) and the gaps are missing.
HAVE = {"holding": {0, 1, 3, 4, 10, 20, 21, 23}}


def make_map(limits: str = "max_gap = 8", timing: str = "turnaround = 0.03",
             points: str = POINTS) -> maps.Map:
    return maps.loads(f"{HEAD}\n[device.limits]\n{limits}\n[device.timing]\n{timing}\n{points}")


def peer_value(a: int) -> int:
    return (7 * a) & 0xFFFF  # tests/peers.py's holding registers


def assert_no_split_points(m: maps.Map, reads: list[tuple[str, int, int]]) -> None:
    for table, address, count in reads:
        for p in m.points.values():
            inside = address <= p.address and p.address + p.count <= address + count
            outside = p.address + p.count <= address or address + count <= p.address
            assert p.table != table or inside or outside, (p.name, address, count)


def expected_fast() -> dict[str, int]:
    return {"a": 0, "b": 7, "c": (21 << 16) | 28, "d": 70}


@pytest.mark.parametrize("transport", ["rtu", "tcp"])
def test_a_refused_bridge_is_remembered_and_the_same_read_returns_every_value(
        transport: str) -> None:
    m = make_map()
    pty, tcp = RefusingPtyPeer(HAVE), RefusingTcpPeer(HAVE)
    peer: Refusing = pty if transport == "rtu" else tcp
    with pty, tcp:
        client: pymb.RtuClient | pymb.TcpClient = (
            pymb.RtuClient(pty.port, 9600, timeout=1.0) if transport == "rtu"
            else pymb.TcpClient("127.0.0.1", tcp.port, timeout=1.0))
        with client:
            dev = MapDevice(client, m, 1, baudrate=9600)
            assert dev.plan("fast").spans == ((0, 11),)  # one bridged request is cheapest
            assert dev.read(group="fast") == expected_fast()
            assert peer.reads() == [("holding", 0, 11), ("holding", 0, 2), ("holding", 3, 2),
                                    ("holding", 10, 1)]
            assert [r.refused for r in peer.log] == [2, 0, 0, 0]
            # remembered: the next read does not try the bridge again
            assert dev.read(group="fast") == expected_fast()
            assert peer.reads()[4:] == [("holding", 0, 2), ("holding", 3, 2), ("holding", 10, 1)]
            assert dev.plan("fast").spans == ((0, 2), (3, 2), (10, 1))
            assert_no_split_points(m, peer.reads())


def test_a_point_refused_alone_is_unsupported_and_retried_later() -> None:
    with RefusingPtyPeer(HAVE) as peer, pymb.RtuClient(peer.port, 9600, timeout=1.0) as client:
        dev = MapDevice(client, make_map(timing="offline_retry = 3600"), 1)
        assert dev.read(group="slow") == {"e": 140, "f": 147, "g": None, "h": 161}
        assert dev.states == {"e": "value", "f": "value", "g": "unsupported", "h": "value"}
        # one request of declared points only, refused: each point alone
        assert peer.reads() == [("holding", 20, 4), ("holding", 20, 1), ("holding", 21, 1),
                                ("holding", 22, 1), ("holding", 23, 1)]
        assert dev.read(group="slow") == {"e": 140, "f": 147, "g": None, "h": 161}
        assert peer.reads()[5:] == [("holding", 20, 2), ("holding", 23, 1)]
    with RefusingPtyPeer(HAVE) as peer, pymb.RtuClient(peer.port, 9600, timeout=1.0) as client:
        dev = MapDevice(client, make_map(timing="offline_retry = 0"), 1)
        dev.read(group="slow")
        dev.read(group="slow")  # retried at once: asks for g again
        assert peer.reads()[5:] == peer.reads()[:5]


def test_a_request_refused_mid_run_falls_back_and_the_run_goes_on() -> None:
    # one request per point, all in one C call: the third is refused, the
    # fourth is still asked in the same read, and so on every read after
    with RefusingPtyPeer(HAVE) as peer, pymb.RtuClient(peer.port, 9600, timeout=1.0) as client:
        m = make_map("single_point_requests = true", "offline_retry = 3600")
        dev = MapDevice(client, m, 1)
        for _ in range(3):
            decoders = dev.read_into(group="slow")
            assert decoders[0].values() == {"e": 140, "f": 147, "g": None, "h": 161}
            assert dev.read(group="slow") == {"e": 140, "f": 147, "g": None, "h": 161}
        assert dev.states == {"e": "value", "f": "value", "g": "unsupported", "h": "value"}
        asked = [("holding", a, 1) for a in (20, 21, 22, 23)]
        assert peer.reads() == asked + [("holding", a, 1) for a in (20, 21, 23)] * 5


def test_without_split_on_exception_the_exception_is_raised() -> None:
    with RefusingPtyPeer(HAVE) as peer, pymb.RtuClient(peer.port, 9600, timeout=1.0) as client:
        dev = MapDevice(client, make_map("max_gap = 8\nsplit_on_exception = false"), 1)
        with pytest.raises(pymb.IllegalDataAddress):
            dev.read(group="fast")
        assert peer.reads() == [("holding", 0, 11)]


def test_limits_on_the_wire_max_registers_and_single_point_requests() -> None:
    floats = "".join(f'\n[[point]]\nname = "v{i}"\naddress = {2 * i}\ntype = "f32"\n'
                     for i in range(64))
    have = {"holding": set(range(128))}
    with RefusingPtyPeer(have, max_count=125) as peer, \
            pymb.RtuClient(peer.port, 9600, timeout=1.0) as client:
        for a in range(128):
            peer.memory.holding[a] = 0
        for i in range(64):
            hi, lo = struct.unpack(">HH", struct.pack(">f", i + 0.5))
            peer.memory.holding[2 * i], peer.memory.holding[2 * i + 1] = hi, lo
        m = make_map("max_registers = 125", "", floats)
        got = MapDevice(client, m, 1).read()
        assert got == {f"v{i}": i + 0.5 for i in range(64)}
        assert peer.reads() == [("holding", 0, 124), ("holding", 124, 4)]  # no torn float
        m = make_map("max_registers = 10", "", floats)
        MapDevice(client, m, 1).read()
        assert [c for _, _, c in peer.reads()[2:]] == [10] * 12 + [8]
        m = make_map("single_point_requests = true", "", floats)
        MapDevice(client, m, 1).read("v0", "v1", "v5")
        assert peer.reads()[15:] == [("holding", 0, 2), ("holding", 2, 2), ("holding", 10, 2)]
        assert all(r.refused == 0 for r in peer.log)


@pytest.mark.parametrize("transport", ["rtu", "tcp"])
def test_turnaround_and_inter_request_gap_are_silences_on_the_wire(transport: str) -> None:
    have = {"holding": {0, 1, 3, 4, 10, 20, 21, 22, 23}}
    for timing, silence in (("turnaround = 0.04", 0.04), ("inter_request_gap = 0.03", 0.03)):
        pty, tcp = RefusingPtyPeer(have), RefusingTcpPeer(have)
        peer: Refusing = pty if transport == "rtu" else tcp
        with pty, tcp:
            client: pymb.RtuClient | pymb.TcpClient = (
                pymb.RtuClient(pty.port, 115200, timeout=1.0) if transport == "rtu"
                else pymb.TcpClient("127.0.0.1", tcp.port, timeout=1.0))
            with client:
                dev = MapDevice(client, make_map("", timing), 1)
                for _ in range(3):
                    dev.read()
            assert len(peer.log) >= 9
            for before, after in pairwise(peer.log):
                # the client heard the reply after the peer sent it
                assert after.arrived - before.replied >= silence


def test_silences_are_the_lines_whichever_device_asked_last() -> None:
    # Three map devices on one client: one keeps no silence (its point "a" is
    # one request the peer answers), one a gap before its requests, one a
    # turnaround after its replies. The gap holds after the silent device's
    # replies too, also for the gap device made after the silent one had read;
    # the turnaround holds before the silent device's next request.
    with RefusingPtyPeer(HAVE) as peer, pymb.RtuClient(peer.port, 115200,
                                                       timeout=1.0) as client:
        plain = MapDevice(client, make_map("", ""), 1)
        plain.read("a")
        gap = MapDevice(client, make_map("", "inter_request_gap = 0.25"), 2)
        slow = MapDevice(client, make_map("", "turnaround = 0.04"), 3)
        for dev in (gap, plain, plain, gap, slow, plain, gap):
            dev.read("a")
    assert [r.slave for r in peer.log] == [1, 2, 1, 1, 2, 3, 1, 2]
    for before, after in pairwise(peer.log):
        heard = after.arrived - before.replied  # the reply was sent before it was heard
        if after.slave == 2:
            assert heard >= 0.25, (before.slave, after.slave)
        if before.slave == 3:
            assert heard >= 0.04, (before.slave, after.slave)


def test_after_connect_waits_before_the_first_request() -> None:
    with RefusingPtyPeer(HAVE) as peer, pymb.RtuClient(peer.port, 9600, timeout=1.0) as client:
        connected = time.monotonic()
        dev = MapDevice(client, make_map("", "after_connect = 0.15"), 1)
        dev.read("a")
        assert peer.log[0].arrived - connected >= 0.15
        dev.read("a")  # the same connection: no second wait needed
        assert len(peer.log) == 2


def test_response_timeout_is_the_reply_timeout_of_its_requests() -> None:
    with RefusingPtyPeer(HAVE) as peer, pymb.RtuClient(peer.port, 9600, timeout=2.0) as client:
        late = [(0.5, rtu(bytes((1, 3, 2, 0, 0))))]
        peer.hook = lambda slave, pdu, normal: late
        dev = MapDevice(client, make_map("", "response_timeout = 0.1"), 1)
        with pytest.raises(ModbusTimeout):
            dev.read("a")  # the client's own 2 s would have waited for it
        assert client.timeout == 2.0


def test_writes_are_checked_before_any_byte_and_use_the_right_function() -> None:
    points = """
[[point]]
name = "setpoint"
address = 30
type = "u16"
access = "rw"
valid = [0, 1000]

[[point]]
name = "limit_a"
address = 32
type = "f32"
access = "rw"

[[point]]
name = "status"
address = 40
type = "u16"

[[point]]
name = "run"
address = 40
type = "bit"
bit = 3
access = "rw"

[[point]]
name = "relay"
table = "coil"
address = 5
type = "bool"
access = "rw"
"""
    have = {"holding": {30, 31, 32, 33, 40}, "coil": {5}}
    with RefusingPtyPeer(have) as peer, pymb.RtuClient(peer.port, 9600, timeout=1.0) as client:
        peer.memory.holding[40] = 0x0100
        dev = MapDevice(client, make_map("", "", points), 1)
        with pytest.raises(InvalidArgument, match="valid range"):
            dev.write("setpoint", 1001)
        with pytest.raises(InvalidArgument, match="read-only"):
            dev.write("status", 3)
        assert peer.log == []
        dev.write("setpoint", 999)
        dev.write("limit_a", 12.5)
        dev.write("run", True)
        dev.write("relay", True)
        # each write is read back
        assert [(r.function, r.address) for r in peer.log] == [
            (6, 30), (3, 30), (16, 32), (3, 32), (3, 40), (6, 40), (3, 40), (5, 5), (1, 5)]
        got = dev.read()
        assert got == {"setpoint": 999, "limit_a": 12.5, "status": 0x0108, "run": True,
                       "relay": True}


@pytest.mark.parametrize("mode", ["tcp", "rtu-over-tcp"])
def test_against_pymodbus_that_lacks_registers(mode: str) -> None:
    pytest.importorskip("pymodbus")
    spec = {"holding": {a: 100 + a for a in HAVE["holding"]}}
    with sparse_pymodbus(mode, spec) as server:
        cls = pymb.TcpClient if mode == "tcp" else pymb.RtuOverTcpClient
        with cls("127.0.0.1", server.port, timeout=2.0) as client:
            dev = MapDevice(client, make_map(), 5, baudrate=9600)
            assert dev.read(group="fast") == {"a": 100, "b": 101, "c": (103 << 16) | 104,
                                              "d": 110}
            assert dev.read(group="slow") == {"e": 120, "f": 121, "g": None, "h": 123}
        packets = server.requests()
    reads = []
    for _, packet in packets:
        pdu = packet[7:] if mode == "tcp" else packet[1:-2]
        _fc, address, count = struct.unpack(">BHH", pdu[:5])
        reads.append((address, count))
    assert reads == [(0, 11), (0, 2), (3, 2), (10, 1),
                     (20, 4), (20, 1), (21, 1), (22, 1), (23, 1)]


def test_exception_03_to_declared_points_reads_each_alone() -> None:
    # The device takes at most 10 registers a request, the map says 125:
    # exception 03 to the one request, then each point alone, all values.
    points = "".join(f'\n[[point]]\nname = "r{i}"\naddress = {i}\ntype = "u16"\n'
                     for i in range(12))
    with RefusingPtyPeer({"holding": set(range(12))}, max_count=10) as peer, \
            pymb.RtuClient(peer.port, 9600, timeout=1.0) as client:
        dev = MapDevice(client, make_map("", "", points), 1)
        assert dev.read() == {f"r{i}": peer_value(i) for i in range(12)}
        assert peer.reads() == [("holding", 0, 12)] + [("holding", i, 1) for i in range(12)]
        assert [r.refused for r in peer.log] == [3] + [0] * 12


def test_two_map_devices_on_one_client_in_two_threads_keep_the_turnaround() -> None:
    import threading

    have = {"holding": {0, 1, 3, 4, 10}}
    with RefusingPtyPeer(have) as peer, \
            pymb.RtuClient(peer.port, 115200, timeout=1.0) as client:
        m = make_map("", "turnaround = 0.03")
        devices = [MapDevice(client, m, 1), MapDevice(client, m, 2)]

        def poll(dev: MapDevice) -> None:
            for _ in range(4):
                dev.read("a", "b")

        threads = [threading.Thread(target=poll, args=(d,)) for d in devices]
        for t in threads:
            t.start()
        for t in threads:
            t.join(10)
        assert {r.slave for r in peer.log} == {1, 2}
        assert len(peer.log) == 8
        for before, after in pairwise(peer.log):
            assert after.arrived - before.replied >= 0.03


def test_a_block_is_written_one_channel_at_a_time() -> None:
    points = """
[[block]]
name = "levels"
first = 50
count = 3
type = "u16"
access = "rw"
"""
    with RefusingPtyPeer({"holding": {50, 51, 52}}) as peer, \
            pymb.RtuClient(peer.port, 9600, timeout=1.0) as client:
        dev = MapDevice(client, make_map("", "", points), 1)
        with pytest.raises(InvalidArgument, match="is a block"):
            dev.write("levels", 7)
        with pytest.raises(InvalidArgument, match=r"channels 1\.\.3"):
            dev.write("levels", 7, channel=4)
        assert dev.write("levels", 7, channel=2) == 7
        assert [(r.function, r.address) for r in peer.log] == [(6, 51), (3, 51)]
        assert dev.read("levels") == {"levels": [peer_value(50), 7, peer_value(52)]}


@pytest.mark.parametrize("firmware", ["2.23", "2.18", "1.07"])
def test_the_hub_through_its_map_reads_what_its_facade_reads(firmware: str) -> None:
    from pymb.devices import SensorHub
    from pymb.sim import SimClock, Simulator

    channels = 50 if firmware == "1.07" else 100
    clock = SimClock(start=1000.0)
    clock.freeze()  # the same values for both readers
    with Simulator([f"hub:7,firmware={firmware}"], clock=clock) as sim, \
            pymb.RtuClient(sim.port, 9600, timeout=2.0) as client:
        reading = SensorHub(client, 7, channels).read_all()
        dev = MapDevice(client, maps.builtin("hub"), 7, options={"channels": channels})
        got = dev.read(group="sweep")
        again = dev.read(group="sweep")
        assert again == got
        # the blocks the firmware lacks are known now: the plan is the reference sweep's
        assert dev.plan("sweep").spans == tuple(
            ref.hub_sweep_spans(reading.unsupported_mask, channels))
        for name, values in reading.as_dict().items():
            states = dev.states[name]
            if name in reading.unsupported:
                assert got[name] == [None] * channels
                assert set(states) == {"unsupported"}
            else:
                assert got[name] == values, name
                assert "unsupported" not in states


def test_another_threads_requests_never_come_between_a_map_devices_requests() -> None:
    # docs/library.md, "Threads": a map device holds the client's lock for a
    # whole read, the silence its map asks for between two requests included
    # (two tables: two runs, the gap kept between them in Python).
    import threading

    points = """
[[point]]
name = "a"
address = 0
type = "u16"

[[point]]
name = "d"
address = 10
type = "u16"
table = "input"
"""
    with RefusingPtyPeer({"holding": {0, 50}, "input": {10}}) as peer, \
            pymb.RtuClient(peer.port, 115200, timeout=1.0) as client:
        dev = MapDevice(client, make_map("", "inter_request_gap = 0.02", points), 1)
        stop = threading.Event()

        def plain() -> None:  # another thread, the client's own requests, flat out
            while not stop.is_set():
                client.read_holding_registers(50, 1, slave=2)

        other = threading.Thread(target=plain)
        other.start()
        try:
            for _ in range(5):
                # tests/peers.py: input register i holds i
                assert dev.read() == {"a": peer_value(0), "d": 10}
        finally:
            stop.set()
            other.join(10)
        mine = [i for i, r in enumerate(peer.log) if r.slave == 1]
        assert [peer.log[i].address for i in mine] == [0, 10] * 5
        assert any(r.slave == 2 for r in peer.log)  # the other thread did ask
        for first, second in zip(mine[::2], mine[1::2], strict=True):
            assert second == first + 1, [(r.slave, r.address) for r in peer.log]
