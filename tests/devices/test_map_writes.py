"""MapDevice writes (the pymb.write/1 contract, section 1-3) against a
scripted Modbus TCP peer that logs every request and can acknowledge a write
without applying it (tests/write_peers.py): the fewest whole-point requests,
read back, refusals that send no byte, the write budget."""

from __future__ import annotations

import struct
from collections.abc import Iterator

import pytest
from write_peers import FreezingTcpPeer, write_map

import pymb
from pymb import maps
from pymb.devices.mapdevice import MapDevice
from pymb.devices.mapwrite import WriteBudget


@pytest.fixture
def peer() -> Iterator[FreezingTcpPeer]:
    with FreezingTcpPeer() as p:
        yield p


def device(peer: FreezingTcpPeer, **kw: str) -> tuple[pymb.TcpClient, MapDevice]:
    c = pymb.TcpClient("127.0.0.1", peer.port, timeout=5.0)
    return c, MapDevice(c, write_map(**kw), 1)


def test_one_register_fc06_then_read_back(peer: FreezingTcpPeer) -> None:
    c, dev = device(peer)
    with c:
        assert dev.write("setpoint_hz", 49.5) == 49.5
    assert peer.memory.holding[10] == 4950
    assert peer.requests == [(1, struct.pack(">BHH", 6, 10, 4950)),
                             (1, struct.pack(">BHH", 3, 10, 1))]


def test_write_multiple_always_uses_fc16(peer: FreezingTcpPeer) -> None:
    c, dev = device(peer, limits='write_multiple = "always"')
    with c:
        assert dev.write("power_limit_pct", 80) == 80
    assert peer.requests[0] == (1, struct.pack(">BHHBH", 16, 11, 1, 2, 80))


def test_adjacent_points_in_one_fc16_and_coils_fc15(peer: FreezingTcpPeer) -> None:
    c, dev = device(peer)
    with c:
        got = dev.write_many({"setpoint_hz": 50, "power_limit_pct": 80, "mode": "run",
                              "target_w": 1500.0, "pump_on": True, "fan_on": False})
    assert got == {"setpoint_hz": 50.0, "power_limit_pct": 80, "mode": "run",
                   "target_w": 1500.0, "pump_on": True, "fan_on": False}
    fcs = peer.functions()
    # coils 5..6 in one FC 15; registers 10..12 in one FC 16, target_w (14..15) in another
    assert fcs[:3] == [15, 16, 16], fcs
    assert peer.requests[1][1][:5] == struct.pack(">BHH", 16, 10, 3)
    assert peer.requests[2][1][:5] == struct.pack(">BHH", 16, 14, 2)
    assert sorted(fcs[3:]) == [1, 3, 3]  # read back: coils 5..6, registers 10..12, 14..15
    assert peer.memory.holding[10:13] == [5000, 80, 1]
    assert peer.memory.coils[5:7] == [1, 0]


def test_one_coil_fc05(peer: FreezingTcpPeer) -> None:
    c, dev = device(peer)
    with c:
        assert dev.write("pump_on", False) is False
    assert peer.requests[0] == (1, struct.pack(">BHH", 5, 5, 0))


def test_a_bit_is_read_changed_and_written_back(peer: FreezingTcpPeer) -> None:
    peer.memory.holding[20] = 0xA001
    c, dev = device(peer)
    with c:
        assert dev.write("relay_2", True) is True
        assert dev.write_many({"relay_2": False, "relay_5": True}) == {
            "relay_2": False, "relay_5": True}
    assert peer.memory.holding[20] == 0xA021
    assert peer.requests[:3] == [(1, struct.pack(">BHH", 3, 20, 1)),
                                 (1, struct.pack(">BHH", 6, 20, 0xA005)),
                                 (1, struct.pack(">BHH", 3, 20, 1))]
    # two bits of one register: one read, one write
    assert peer.functions()[3:] == [3, 6, 3]


def test_mask_write_fc22_sends_no_read_first(peer: FreezingTcpPeer) -> None:
    peer.memory.holding[20] = 0xA001
    peer.memory.holding[21] = 0x1234
    c, dev = device(peer, limits="mask_write = true")
    with c:
        assert dev.write_many({"relay_2": True, "relay_5": True, "level": 0x56}) == {
            "relay_2": True, "relay_5": True, "level": 0x56}
    assert peer.requests[:2] == [(1, struct.pack(">BHHH", 22, 20, 0xFFDB, 0x0024)),
                                 (1, struct.pack(">BHHH", 22, 21, 0xFF00, 0x0056))]
    assert peer.memory.holding[20:22] == [0xA025, 0x1256]


@pytest.mark.parametrize("limits", ["", "[device.limits]\nmask_write = true\n"])
def test_a_wide_view_writes_only_the_register_that_holds_its_bits(peer: FreezingTcpPeer,
                                                                   limits: str) -> None:
    m = maps.loads('schema = "pymb.map/1"\n[device]\nid = "wide"\ntable = "holding"\n'
                   + limits + '[[point]]\nname = "alarm"\naddress = 2\ntype = "bit"\n'
                   'count = 2\nbit = 17\norder = "CDAB"\naccess = "rw"\n', source="w.toml")
    peer.memory.holding[2:4] = [0x1234, 0x8000]
    with pymb.TcpClient("127.0.0.1", peer.port, timeout=5.0) as c:
        assert MapDevice(c, m, 1).write("alarm", True) is True
    writes = [pdu for _, pdu in peer.requests if pdu[0] in (6, 16, 22)]
    # bit 17 of a CDAB pair is bit 1 of the second register: the first is left alone
    assert writes == ([struct.pack(">BHHH", 22, 3, 0xFFFD, 0x0002)] if limits
                      else [struct.pack(">BHH", 6, 3, 0x8002)])
    assert peer.memory.holding[2:4] == [0x1234, 0x8002]


def test_block_channel_by_keyword_or_column_name(peer: FreezingTcpPeer) -> None:
    c, dev = device(peer)
    with c:
        assert dev.write("zone_c", 21.5, channel=3) == 21.5
        assert dev.write_many({"zone_c_4": 19.0}) == {"zone_c_4": 19.0}
    assert peer.memory.holding[42:44] == [215, 190]


def test_no_verify_reads_nothing_and_returns_none(peer: FreezingTcpPeer) -> None:
    c, dev = device(peer)
    with c:
        assert dev.write("mode", "stop", verify=False) is None
        assert dev.write("reset", 1) is None  # write-only: never read back
    assert peer.functions() == [6, 6]


@pytest.mark.parametrize(("call", "message"), [
    (lambda d: d.write("setpoint_hz", 70), "outside its valid range 45..65"),
    (lambda d: d.write("setpoint_hz", "fast"), "a number is needed"),
    (lambda d: d.write("setpont_hz", 50), "no point 'setpont_hz'; did you mean 'setpoint_hz'?"),
    (lambda d: d.write("firmware", 3), "read-only"),
    (lambda d: d.write("voltage_v", 3), "read-only"),
    (lambda d: d.write("mode", "running"), "is not one of its values; did you mean 'run'?"),
    (lambda d: d.write("mode", 7), "is not one of its values"),
    (lambda d: d.write("zone_c", 20.0), "is a block"),
    (lambda d: d.write("zone_c", 20.0, channel=5), "channels 1..4"),
    (lambda d: d.write("zone_c_9", 20.0), "no point 'zone_c_9'"),
    (lambda d: d.write("power_limit_pct", 80.5), "a whole number is needed"),
    (lambda d: d.write("pump_on", 2), "true or false"),
    (lambda d: d.write_many({"setpoint_hz": 50, "power_limit_pct": 101}), "outside"),
    (lambda d: d.write_many({"firmware": 1, "relay_2": True}), "read-only"),
])
def test_every_refusal_sends_no_byte(peer: FreezingTcpPeer, call: object,
                                     message: str) -> None:
    c, dev = device(peer)
    with c, pytest.raises(pymb.InvalidArgument) as info:
        call(dev)  # type: ignore[operator]
    assert message in str(info.value)
    assert "wdev" in str(info.value)
    assert peer.requests == []


def test_two_values_sharing_register_bits_are_refused_whole(peer: FreezingTcpPeer) -> None:
    c, dev = device(peer)
    with c, pytest.raises(pymb.InvalidArgument, match="share registers"):
        dev.write_many({"relay_2": True, "status": 3, "setpoint_hz": 50})
    with pytest.raises(pymb.InvalidArgument):
        dev.write_many({"zone_c_1": 10.0, "zone_c": 5})
    assert peer.requests == []


def test_acknowledged_but_not_applied_raises_write_not_applied(peer: FreezingTcpPeer) -> None:
    peer.memory.holding[10] = 5000
    peer.frozen.add(10)
    c, dev = device(peer)
    with c, pytest.raises(pymb.WriteNotApplied) as info:
        dev.write("setpoint_hz", 49.5)
    e = info.value
    assert isinstance(e, pymb.ModbusError)
    assert (e.point, e.sent, e.found) == ("setpoint_hz", 49.5, 50.0)
    assert str(e) == (f"wdev:1 on 127.0.0.1:{peer.port}: not applied: 'setpoint_hz': "
                      "sent 49.5, the device holds 50.0")
    assert peer.functions() == [6, 3]


def test_write_many_says_which_points_were_applied(peer: FreezingTcpPeer) -> None:
    peer.frozen_coils.add(6)
    c, dev = device(peer)
    with c, pytest.raises(pymb.WriteNotApplied) as info:
        dev.write_many({"mode": "run", "fan_on": False})
    assert info.value.applied == {"mode": "run"}
    assert info.value.point == "fan_on"
    assert "applied: mode" in str(info.value)


def test_a_device_exception_names_what_was_written_before(peer: FreezingTcpPeer) -> None:
    def refuse_fc16(slave: int, pdu: bytes, normal: bytes | None) -> list[tuple[float, bytes]]:
        if pdu[0] == 16:
            return [(0.0, peer.frame(slave, bytes((0x90, 4))))]
        return [(0.0, peer.frame(slave, normal or b""))]
    peer.hook = refuse_fc16
    c, dev = device(peer)
    with c, pytest.raises(pymb.DeviceFailure) as info:
        dev.write_many({"pump_on": True, "target_w": 10.0})
    assert info.value.applied == ["pump_on"]  # type: ignore[attr-defined]
    assert "written before the failure: pump_on" in str(info.value)


def test_budget_refuses_before_anything_is_sent(peer: FreezingTcpPeer) -> None:
    now = [1000.0]
    c = pymb.TcpClient("127.0.0.1", peer.port, timeout=5.0)
    dev = MapDevice(c, write_map(budget="max_writes_per_hour = 2"), 1,
                    budget=WriteBudget(lambda: now[0]))
    with c:
        assert dev.write("setpoint_hz", 50) == 50.0
        assert dev.write("setpoint_hz", 51) == 51.0
        n = len(peer.requests)
        with pytest.raises(pymb.WriteRefused) as info:
            dev.write("setpoint_hz", 52)
        assert info.value.reason == "budget"
        assert str(info.value) == ("wdev:1: 'setpoint_hz': write budget spent (2 writes per "
                                   "hour); nothing was sent")
        assert len(peer.requests) == n  # not a byte, not even a read
        now[0] += 3600.5  # the sliding hour has passed
        assert dev.write("setpoint_hz", 52) == 52.0


def test_a_held_value_is_applied_without_being_sent_and_not_counted(
        peer: FreezingTcpPeer) -> None:
    c, dev = device(peer, device="max_writes_per_hour = 1")
    peer.memory.holding[10] = 5000
    with c:
        for _ in range(3):
            out = dev.write_points([("setpoint_hz", None, 50.0)])
            assert (out[0].before, out[0].after, out[0].applied, out[0].sent) == (
                50.0, 50.0, True, False)
        assert peer.functions() == [3, 3, 3]  # read first, nothing written
        assert dev.write("setpoint_hz", 49) == 49.0  # the budget's one write
        with pytest.raises(pymb.WriteRefused):
            dev.write("setpoint_hz", 48)
        # the [device] budget is per point: another point has its own
        assert dev.write("power_limit_pct", 3) == 3


def test_a_blocks_budget_is_counted_for_each_channel(peer: FreezingTcpPeer) -> None:
    m = maps.loads('schema = "pymb.map/1"\n[device]\nid = "b"\ntable = "holding"\n'
                   '[[block]]\nname = "zone_c"\nfirst = 0\ncount = 3\ntype = "u16"\n'
                   'access = "rw"\nmax_writes_per_hour = 1\n', source="b.toml")
    with pymb.TcpClient("127.0.0.1", peer.port, timeout=5.0) as c:
        dev = MapDevice(c, m, 1)
        assert dev.write_many({"zone_c_1": 5, "zone_c_2": 5}) == {"zone_c_1": 5, "zone_c_2": 5}
        sent = len(peer.requests)
        with pytest.raises(pymb.WriteRefused) as info:
            dev.write("zone_c", 6, channel=1)
        assert info.value.reason == "budget"
        assert len(peer.requests) == sent
        assert dev.write("zone_c", 7, channel=3) == 7


def test_plan_write_lists_the_requests_and_sends_nothing(peer: FreezingTcpPeer) -> None:
    c, dev = device(peer)
    lines = [r.describe() for r in dev.plan_write({"setpoint_hz": 49.5, "power_limit_pct": 80,
                                                   "relay_2": True, "pump_on": True})]
    assert lines == [
        "FC 05 coil 5: 1 (pump_on)",
        "FC 16 holding 10: 0x1356 0x0050 (setpoint_hz, power_limit_pct)",
        "FC 06 holding 20: read (FC 03), then 0x0004 with the other bits as read (relay_2)",
    ]
    assert peer.requests == []
    c.close()
