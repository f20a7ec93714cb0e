"""Sparkplug B DCMD writes end to end: ``pymb log --mqtt-profile sparkplug``
in its own process, Debian's mosquitto, a scripted RTU device on a real
pseudo-terminal that logs every request (and can acknowledge a write without
applying it), and DCMDs encoded, DBIRTH and DDATA decoded, by pysparkplug's
``Payload`` (protobuf's runtime, independent of pymb's own encoder).

By name and by alias; the answer is a DDATA of the DCMD's metrics read back;
refused metrics (range, not allowed, read-only, unknown) send no write and
the DDATA carries the current value; the DBIRTH's ``writable`` property only
on the points a DCMD may write; every metric in the ``writes`` view."""

from __future__ import annotations

import re
import shlex
import sqlite3
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from conftest import PYMB, PYMB_ENV, run_pymb, wait_until
from docblocks import claim_one
from mqtt_broker import Fleet, fleet, mosquitto, sparkplug_pb  # noqa: F401 (fixtures)
from sparkplug_host import DEVICE, DOUBLE, UINT16, Host, start
from write_mqtt import rows, stop, writes_sent
from write_peers import WRITE_MAP, FreezingPtyPeer

from pymb.sim import SimulatorProcess

paho = pytest.importorskip("paho.mqtt.client")

INVERTER = claim_one("docs/writes.md", "toml", how="load", contains='id = "acme-inverter"').text
SHELL = claim_one("docs/writes.md", "sh", how="run", contains="--mqtt-profile sparkplug").text
RECORD = claim_one("docs/writes.md", "csv", how="compare", contains="sparkplug").text


@pytest.fixture
def peer() -> Iterator[FreezingPtyPeer]:
    with FreezingPtyPeer() as p:
        p.memory.holding[10] = 5000  # setpoint_hz 50.00
        p.memory.holding[11] = 40  # power_limit_pct
        p.memory.holding[12] = 0  # mode stop
        p.memory.holding[25] = 7  # firmware
        for c in range(4):
            p.memory.holding[40 + c] = 200  # zone_c 20.0
        yield p


def _props(m: Any) -> dict[str, Any]:
    return {k: getattr(v, v.WhichOneof("value"))
            for k, v in zip(m.properties.keys, m.properties.values, strict=True)}


def _events(db: Path) -> list[str]:
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    try:
        return [r[0] for r in con.execute("SELECT message FROM events")]
    finally:
        con.close()


def test_dcmd_by_name_and_alias_refusals_birth_and_record(
        fleet: Fleet, peer: FreezingPtyPeer, tmp_path: Path,  # noqa: F811
        sparkplug_pb: Any) -> None:  # noqa: F811
    map_file = tmp_path / "wdev.toml"
    map_file.write_text(WRITE_MAP.format(device="", limits="", budget=""))
    broker = fleet.broker()
    db = tmp_path / "log.sqlite"
    host = Host(fleet, broker, sparkplug_pb)
    proc = start(fleet, broker, peer, map_file, db)
    try:
        try:
            birth = host.birth()
        except AssertionError:
            proc.kill()
            raise AssertionError(proc.communicate()[1]) from None
        aliases = {m.name: m.alias for m in birth.metrics}
        props = {m.name: _props(m) for m in birth.metrics}
        # writable in the map AND allowed: exactly these (firmware is allowed but read-only;
        # power_limit_pct and the relays are writable but not allowed)
        assert {n for n, p in props.items() if p.get("writable") is True} == {
            "setpoint_hz", "mode", "channel 002/zone_c"}
        assert all("writable" not in p for n, p in props.items()
                   if n not in ("setpoint_hz", "mode", "channel 002/zone_c"))
        assert props["setpoint_hz"]["engUnit"] == "Hz"

        # by name: written, read back, answered
        n = len(host.sub.snapshot())
        host.dcmd(("setpoint_hz", DOUBLE, 49.5), seq=0)
        assert host.answer(n, aliases) == {"setpoint_hz": 49.5}
        assert peer.memory.holding[10] == 4950
        sent = len(writes_sent(peer))
        assert sent == 1

        # by alias, a block's channel by name
        n = len(host.sub.snapshot())
        host.dcmd((aliases["mode"], UINT16, 1), ("channel 002/zone_c", DOUBLE, 21.5))
        assert host.answer(n, aliases) == {"mode": 1, "channel 002/zone_c": 21.5}
        assert peer.memory.holding[12] == 1
        assert peer.memory.holding[41] == 215
        sent = len(writes_sent(peer))

        # the current values have been polled since: the refusals' DDATA carries them
        def polled(ms: Any) -> bool:
            return any(m.alias == aliases["setpoint_hz"] and m.double_value == 49.5
                       for d in host.decoded("DDATA", n, ms) for m in d.metrics
                       if any(x.alias == aliases["sample"] for x in d.metrics))
        host.sub.wait_until(polled, 60, "a poll after the writes")
        refusals: list[tuple[list[tuple[str | int, int, Any]], dict[str, Any]]] = [
            ([("setpoint_hz", DOUBLE, 70.0)], {"setpoint_hz": 49.5}),  # range
            ([(aliases["mode"], UINT16, 7)], {"mode": 1}),  # not one of its values
            ([("power_limit_pct", UINT16, 50)], {"power_limit_pct": 40}),  # not allowed
            ([("firmware", UINT16, 9)], {"firmware": 7}),  # read-only
            ([("channel 001/zone_c", DOUBLE, 20.5)], {"channel 001/zone_c": 20.0}),
            # one refused metric refuses the whole DCMD
            ([("setpoint_hz", DOUBLE, 48.0), ("mode", UINT16, 9)],
             {"setpoint_hz": 49.5, "mode": 1}),
        ]
        for metrics, answer in refusals:
            n = len(host.sub.snapshot())
            host.dcmd(*metrics)
            assert host.answer(n, aliases) == answer, metrics
        assert len(writes_sent(peer)) == sent  # not one refusal wrote
        assert peer.memory.holding[10] == 4950

        # a metric the DBIRTH does not have, by name and by alias: refused, recorded
        host.dcmd(("setpont_hz", DOUBLE, 50.0))
        host.dcmd((999999, DOUBLE, 50.0))
        wait_until(lambda: len(rows(db)) >= 12, "the unknown metrics on record", 60)
        assert len(writes_sent(peer)) == sent

        # the same DCMD again (same timestamp and seq): not executed again
        peer.memory.holding[10] = 5000
        stamp = host.stamp - 100
        n = len(host.sub.snapshot())
        host.dcmd(("setpoint_hz", DOUBLE, 49.5), seq=0, timestamp=stamp)
        host.answer(n, aliases)
        sent = len(writes_sent(peer))
        n = len(host.sub.snapshot())
        host.dcmd(("setpoint_hz", DOUBLE, 49.5), seq=0, timestamp=stamp)
        host.answer(n, aliases)
        assert len(writes_sent(peer)) == sent

        # acknowledged and not applied: the DDATA carries what the device holds
        peer.frozen.add(10)
        peer.memory.holding[10] = 5000
        n = len(host.sub.snapshot())
        host.dcmd(("setpoint_hz", DOUBLE, 46.0))
        assert host.answer(n, aliases) == {"setpoint_hz": 50.0}
        assert len(writes_sent(peer)) == sent + 1

        # across a restart of the logger: the DCMD on record is not executed again
        stop(proc)
        peer.frozen.clear()
        sent = len(writes_sent(peer))
        n = len(host.sub.snapshot())
        proc = start(fleet, broker, peer, map_file, db)
        host.sub.wait_until(lambda ms: any("/DBIRTH/" in t for t, _ in ms[n:]), 60,
                            "the DBIRTH after the restart")
        n = len(host.sub.snapshot())
        host.dcmd(("setpoint_hz", DOUBLE, 49.5), seq=0, timestamp=stamp)
        assert host.answer(n, aliases) == {"setpoint_hz": 50.0}
        assert len(writes_sent(peer)) == sent
    finally:
        host.close()
    stop(proc)

    got = rows(db)
    assert {r[0] for r in got} == {"sparkplug"}
    first = got[0]
    assert first[1].startswith(f"sparkplug:{DEVICE}:")
    assert first[1].endswith(":0")
    assert first[2:] == (DEVICE, "setpoint_hz", "49.5", "50.0", "49.5", 1, None)
    by_point = [(r[3], r[7], r[8]) for r in got]
    assert by_point[1:3] == [("mode", 1, None), ("zone_c_2", 1, None)]
    assert by_point[3:9] == [("setpoint_hz", 0, "range"), ("mode", 0, "range"),
                             ("power_limit_pct", 0, "not_allowed"),
                             ("firmware", 0, "not_allowed"), ("zone_c_1", 0, "not_allowed"),
                             ("setpoint_hz", 0, "range")]
    assert by_point[9] == ("mode", 0, "range")
    assert by_point[10:12] == [("setpont_hz", 0, "invalid"), ("alias 999999", 0, "invalid")]
    assert by_point[-1] == ("setpoint_hz", 0, "not_applied")
    assert got[-1][6] == "50.0"
    events = "\n".join(_events(db))
    assert "'setpont_hz' names no metric of the DBIRTH" in events
    assert "not in the allow list" in events
    assert events.count("was received before: not executed again") == 2
    assert "not applied" in events


def test_the_docs_sparkplug_example_runs_and_records_what_it_shows(
        fleet: Fleet, tmp_path: Path, sparkplug_pb: Any) -> None:  # noqa: F811
    (tmp_path / "inverter.toml").write_text(INVERTER)
    simulate, log = (line[2:] for line in SHELL.splitlines() if line.startswith("$ "))
    endpoint = simulate.split("--tcp ")[1].split()[0]
    args = shlex.split(simulate)[2:]
    args[args.index("--tcp") + 1] = "127.0.0.1:0"
    args[args.index("inverter.toml")] = str(tmp_path / "inverter.toml")
    argv = shlex.split(log)
    assert argv[:2] == ["pymb", "log"]
    group, node = argv[argv.index("--mqtt-group") + 1], argv[argv.index("--mqtt-node") + 1]
    shown = RECORD.splitlines()
    stamps = [int(line.split(",")[2].split(":")[2]) for line in shown[1:]]
    broker = fleet.broker()
    with SimulatorProcess(args, quiet=True) as sim:
        argv = shlex.split(log.replace(endpoint, sim.endpoint).replace(
            "mqtt://127.0.0.1:1883", f"mqtt://127.0.0.1:{broker.port}"))
        host = Host(fleet, broker, sparkplug_pb, group, node, "inv-1")
        proc = subprocess.Popen([*PYMB, *argv[1:]], cwd=tmp_path, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True, env=PYMB_ENV)
        fleet.children.append(proc)
        try:
            aliases = {m.name: m.alias for m in host.birth().metrics}
            for metric, dt, value, stamp, answer in [
                ("frequency_setpoint_hz", DOUBLE, 49.5, stamps[0], 49.5),
                ("frequency_setpoint_hz", DOUBLE, 70.0, stamps[1], 49.5),
                (aliases["power_limit_pct"], UINT16, 80, stamps[2], 100),
            ]:
                n = len(host.sub.snapshot())
                host.dcmd((metric, dt, value), timestamp=stamp)
                name = metric if isinstance(metric, str) else "power_limit_pct"
                assert host.answer(n, aliases) == {name: answer}
        finally:
            host.close()
        stop(proc)
    out = run_pymb("export", "--writes", "plant.sqlite", cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    time_column = re.compile(r"^\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}Z,")
    got = [time_column.sub("T,", line) for line in out.stdout.splitlines()]
    assert got == [time_column.sub("T,", line) for line in shown]
    assert all(time_column.match(line) for line in out.stdout.splitlines()[1:])


def test_dcmd_values_of_every_datatype_as_pysparkplug_encodes_them(sparkplug_pb: Any) -> None:  # noqa: F811
    from pymb.fleet.protobuf import command_values

    p = sparkplug_pb()
    p.timestamp, p.seq = 1796299201234, 7
    cases: list[tuple[int, str, Any]] = [
        (1, "int_value", -5), (2, "int_value", -300), (3, "int_value", -70000),
        (4, "long_value", -(2 ** 40)), (5, "int_value", 200), (6, "int_value", 65535),
        (7, "int_value", 4000000000), (8, "long_value", 2 ** 63), (9, "float_value", 1.5),
        (10, "double_value", -49.25), (11, "boolean_value", True),
        (12, "string_value", "héllo"),
    ]
    for i, (dt, field, value) in enumerate(cases):
        m = p.metrics.add()
        m.name, m.datatype = f"m{i}", dt
        # protobuf keeps a negative int in uint32/uint64 fields as its two's complement
        bits = 64 if field == "long_value" else 32
        setattr(m, field, value & ((1 << bits) - 1) if isinstance(value, int)
                and not isinstance(value, bool) else value)
    null = p.metrics.add()
    null.alias, null.datatype, null.is_null = 42, 10, True
    ts, seq, metrics = command_values(p.SerializeToString())
    assert (ts, seq) == (1796299201234, 7)
    assert metrics[:-1] == [(f"m{i}", None, v) for i, (_, _, v) in enumerate(cases)]
    assert metrics[-1] == (None, 42, None)
    with pytest.raises(ValueError, match="truncated"):
        command_values(b"\x12\x05\x0a\x01")


def test_a_dcmd_for_a_device_gone_silent_fails_fast_with_reason_device(
        fleet: Fleet, peer: FreezingPtyPeer, tmp_path: Path,  # noqa: F811
        sparkplug_pb: Any) -> None:  # noqa: F811
    map_file = tmp_path / "wdev.toml"
    map_file.write_text(WRITE_MAP.format(device="", limits="", budget=""))
    broker = fleet.broker()
    db = tmp_path / "log.sqlite"
    host = Host(fleet, broker, sparkplug_pb)
    proc = start(fleet, broker, peer, map_file, db)
    try:
        aliases = {m.name: m.alias for m in host.birth().metrics}
        peer.slaves = {9}  # unit 1 stops answering: after its missed polls, a DDEATH
        host.sub.wait_until(lambda ms: any("/DDEATH/" in t for t, _ in ms), 60, "a DDEATH")
        polls = len(peer.requests)
        t0 = time.monotonic()
        n = len(host.sub.snapshot())
        host.dcmd(("setpoint_hz", DOUBLE, 49.5))
        assert host.answer(n, aliases) == {"setpoint_hz": 50.0}  # its last value
        assert time.monotonic() - t0 < 5.0
        assert not [p for _, p in list(peer.requests)[polls:] if p[0] in (5, 6, 15, 16, 22)]
        wait_until(lambda: len(rows(db)) == 1, "the DCMD on record", 30)
    finally:
        host.close()
    peer.slaves = None
    stop(proc)
    (row,) = rows(db)
    assert (row[0], row[3], row[7], row[8]) == ("sparkplug", "setpoint_hz", 0, "device")
