"""Reliability: the fault matrix (every simulator fault at every layer:
client, facades, logger), unplug/replug 1,000 times without leaks, disk full
and read-only output, and the logger killed at random moments.

For each fault: the right typed error or a transparent retry, never a wrong
value, never a stale value, the next good request succeeds, and no call takes
longer than the timeout plus one quiet period of the same length (pymb's
guard against late replies).
"""

from __future__ import annotations

import gc
import random
import signal
import sqlite3
import subprocess
import sys
import threading
import time
from array import array
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import reference as ref
from conftest import PYMB, PYMB_ENV, TIMEOUT, open_fds, rss_kb, wait_until
from dbwait import count, wait_for

import pymb
from pymb.devices import CoolPro, SensorHub
from pymb.logger import BusConfig, DeviceConfig, LogConfig, Logger
from pymb.sim import SimClock, Simulator
from pymb.store import OutputError, SqliteSink

# The client's timeout: at least 0.5 s, so that a loaded machine (three test workers
# on two cores) answers a good or a wrong reply before it passes.
T = max(TIMEOUT, 0.5)

# fault -> (parameters, what the client must raise; None: the reply is good)
MATRIX: dict[str, tuple[dict[str, Any], Any]] = {
    "no_reply": ({}, pymb.ModbusTimeout),
    "late": ({"delay": 1.6 * T}, pymb.ModbusTimeout),
    "bad_crc": ({}, pymb.ProtocolError),
    "truncate": ({}, (pymb.ModbusTimeout, pymb.ProtocolError)),
    "stray": ({}, None),
    "wrong_address": ({}, pymb.ProtocolError),
    "exception:01": ({"code": 1}, pymb.IllegalFunction),
    "exception:02": ({"code": 2}, pymb.IllegalDataAddress),
    "exception:03": ({"code": 3}, pymb.IllegalDataValue),
    "exception:04": ({"code": 4}, pymb.DeviceFailure),
    "busy": ({}, pymb.DeviceFailure),  # CoolPro: 04; the hub facade retries it
    "sensor": ({"seconds": 0.5}, None),
    "unplug": ({"seconds": 0.4}, pymb.ModbusConnectionError),
}


def kind_of(name: str) -> str:
    return name.split(":")[0]


@pytest.fixture
def frozen_sim() -> Iterator[Simulator]:
    clock = SimClock(start=100.0)
    clock.freeze()
    with Simulator(["coolpro", "hub:250"], seed=21, clock=clock) as s:
        yield s


def expect(outcome: Any, call: Callable[[], Any]) -> tuple[Any, float]:
    t0 = time.monotonic()
    result = None
    if outcome is None:
        result = call()
    else:
        with pytest.raises(outcome):
            call()
    return result, time.monotonic() - t0


def wait_plugged(sim: Simulator) -> None:
    wait_until(lambda: sim.plugged, "the simulator's port to come back", timeout=5)


def bound(name: str) -> float:
    # The timeout, then a quiet period of one timeout (stretched by the late
    # reply itself when one arrives), plus scheduling slack.
    return 4 * T + 0.4 + float(MATRIX[name][0].get("delay", 0.0))


@pytest.mark.parametrize("name", list(MATRIX))
def test_client_layer(frozen_sim: Simulator, name: str) -> None:
    params, outcome = MATRIX[name]
    dev = frozen_sim.device(40)
    dev.pin("input_voltage_v", 11111)  # type: ignore[attr-defined]
    with pymb.RtuClient(frozen_sim.port, timeout=T, slave=40) as c:
        assert c.read_input_registers(0, 1)[0] == 11111
        frozen_sim.faults.inject(kind_of(name), address=40, **params)
        result, took = expect(outcome, lambda: c.read_input_registers(0, 8))
        assert took < bound(name), took
        if result is not None:
            assert result[0] == 11111  # a good reply is the right one
        dev.pin("input_voltage_v", 22222)  # type: ignore[attr-defined]
        if name == "unplug":
            wait_plugged(frozen_sim)
        # The next good request gets fresh data: never the faulty or late reply.
        assert c.read_input_registers(0, 8)[0] == 22222
        assert c.read_input_registers(0, 1)[0] == 22222


@pytest.mark.parametrize("name", list(MATRIX))
def test_coolpro_facade_layer(frozen_sim: Simulator, name: str) -> None:
    params, outcome = MATRIX[name]
    dev = frozen_sim.device(40)
    dev.pin("temperature_c", 25800)  # type: ignore[attr-defined]
    with pymb.RtuClient(frozen_sim.port, timeout=T) as c:
        cp = CoolPro(c, 40)
        frozen_sim.faults.inject(kind_of(name), address=40, **params)
        result, took = expect(outcome, cp.read_telemetry)
        assert took < bound(name)
        if result is not None:
            assert result.temperature_c == 25.8
        dev.pin("temperature_c", 30000)  # type: ignore[attr-defined]
        if name == "unplug":
            wait_plugged(frozen_sim)
        assert cp.read_telemetry().temperature_c == 30.0


@pytest.mark.parametrize("name", list(MATRIX))
def test_hub_facade_layer(frozen_sim: Simulator, name: str) -> None:
    params, outcome = MATRIX[name]
    if name in ("busy", "exception:04", "exception:02"):
        # [HUB] 04 = busy: retried transparently. 02 on a span makes the sweep
        # read that span block by block (in case the firmware lacks one): a
        # passing 02 is absorbed and every block still arrives.
        outcome = None
    dev = frozen_sim.device(250)
    dev.pin("temperature_c", 1, 215)  # type: ignore[attr-defined]
    with pymb.RtuClient(frozen_sim.port, timeout=T) as c:
        hub = SensorHub(c, 250, busy_backoff=0.01)
        assert hub.read_all().temperature_c[0] == 21.5
        frozen_sim.faults.inject(kind_of(name), address=250, **params)
        result, took = expect(outcome, hub.read_all)
        assert took < bound(name) + 6 * 0.01
        if result is not None:
            assert result.temperature_c[0] == 21.5
            assert list(result.registers) == list(dev.registers())  # type: ignore[attr-defined]
        dev.pin("temperature_c", 1, 0x8000 | 55)  # type: ignore[attr-defined]
        if name == "unplug":
            wait_plugged(frozen_sim)
        r = hub.read_all()
        assert r.temperature_c[0] == -5.5
        assert list(r.registers) == list(dev.registers())  # type: ignore[attr-defined]


def test_hub_busy_beyond_retries_raises_device_busy(frozen_sim: Simulator) -> None:
    frozen_sim.faults.inject("busy", count=5, address=250)
    with pymb.RtuClient(frozen_sim.port, timeout=T) as c:
        with pytest.raises(pymb.DeviceBusy):
            SensorHub(c, 250, busy_retries=3, busy_backoff=0.001).read_all()
        frozen_sim.faults.clear()
        assert len(SensorHub(c, 250).read_all().temperature_c) == 100


def test_logger_layer_records_every_fault_and_never_stores_wrong_values(
        tmp_path: Path) -> None:
    db = tmp_path / "matrix.sqlite"
    with Simulator(["coolpro", "hub"], seed=8) as sim:
        bus = BusConfig("b", sim.port, timeout=T, devices=[DeviceConfig("coolpro", 40),
                                                           DeviceConfig("hub", 1)])
        # Commits twice a second: the test waits on what is committed.
        logger = Logger(LogConfig([bus], "sqlite", str(db), commit_interval=0.5))
        result: list[Any] = []
        t = threading.Thread(target=lambda: result.append(logger.run(300)))  # stopped below
        t.start()

        def meet(name: str, params: dict[str, Any]) -> None:
            kind = kind_of(name)
            met = sim.faults.counts[kind]
            sim.faults.inject(kind, address=40, **params)
            # One of the logger's requests meets the fault...
            wait_until(lambda: sim.faults.counts[kind] > met,
                       f"the logger's request that meets {name}", timeout=20, alive=t.is_alive)
            # ...and the bus is answered again (after an unplug: reconnected).
            served = sim.stats.replies
            wait_until(lambda: sim.stats.replies >= served + 3,
                       f"three more replies after {name}", timeout=20, alive=t.is_alive)

        try:
            for name, (params, _) in MATRIX.items():
                meet(name, params)
            # Logging goes on after the last fault: samples read from now on,
            # committed, and enough CoolPro rows to check below.
            settled = time.time()
            wait_for(db, "SELECT COUNT(*) FROM coolpro", at_least=21, timeout=30)
            wait_for(db, "SELECT COUNT(*) FROM samples WHERE time_utc > ?", (settled,),
                     at_least=4, timeout=30)
        finally:
            logger.stop()
            t.join(30)
    assert not t.is_alive()
    summary = result[0]
    assert summary.faults >= 9
    con = sqlite3.connect(db)
    assert con.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    kinds = {k for (k,) in con.execute("SELECT DISTINCT kind FROM events")}
    assert {"timeout", "protocol", "exception", "connection", "reconnect"} <= kinds
    # Every stored value is the decode of the raw registers stored with it.
    rows = con.execute("SELECT s.registers, c.input_voltage_v, c.uptime_s, c.status "
                       "FROM samples s JOIN coolpro c ON c.sample_id = s.id").fetchall()
    assert len(rows) > 20
    for blob, v, uptime, status in rows:
        regs = array("H", blob)
        if sys.byteorder == "little":
            regs.byteswap()
        decoded = ref.coolpro_telemetry(list(regs))
        assert (decoded[0], decoded[5], decoded[6]) == (v, uptime, status)
    # Logging went on after the last fault.
    last_fault = con.execute("SELECT MAX(time_utc) FROM events WHERE kind != 'reconnect'"
                             ).fetchone()[0]
    assert con.execute("SELECT COUNT(*) FROM samples WHERE time_utc > ?",
                       (last_fault,)).fetchone()[0] > 3
    con.close()


# -- unplug and replug ------------------------------------------------------------


@pytest.mark.parametrize("cycles", [1000])
def test_unplug_replug_without_leaks(cycles: int) -> None:
    with Simulator(["coolpro"], seed=2) as sim:
        c = pymb.RtuClient(sim.port, timeout=T, slave=40)
        c.connect()
        try:
            def cycle() -> None:
                sim.unplug()
                with pytest.raises(pymb.ModbusConnectionError):
                    c.read_input_registers(0, 8)
                sim.replug()
                assert len(c.read_input_registers(0, 8)) == 8

            for _ in range(50):  # warm up caches and allocators
                cycle()
            gc.collect()
            fd0, rss0 = open_fds(), rss_kb()
            for _ in range(cycles):
                cycle()
            gc.collect()
            assert open_fds() == fd0
            assert rss_kb() - rss0 < 2048, (rss0, rss_kb())
            assert c.connections == cycles + 51
        finally:
            c.close()


# -- output failures ------------------------------------------------------------


def test_disk_full_is_a_clear_error_and_keeps_what_was_committed(tmp_path: Path) -> None:
    db = tmp_path / "full.sqlite"
    with Simulator(["hub"], seed=3) as sim:
        bus = BusConfig("b", sim.port, timeout=1.0, devices=[DeviceConfig("hub", 1)])
        sink = SqliteSink(db)
        # SQLite's own "database or disk is full" (SQLITE_FULL), at ~2 MB.
        sink.db.execute("PRAGMA max_page_count = 500")
        logger = Logger(LogConfig([bus], "sqlite", str(db)), sink=sink)
        t0 = time.monotonic()
        with pytest.raises(OutputError, match="full") as ei:
            logger.run(60)
        assert time.monotonic() - t0 < 30
    assert "committed before is intact" in str(ei.value)
    con = sqlite3.connect(db)
    assert con.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    n = con.execute("SELECT COUNT(*) FROM samples").fetchone()[0]
    assert n > 0
    assert con.execute("SELECT COUNT(*) FROM hub").fetchone()[0] == 100 * n
    con.close()


def test_read_only_database_is_a_clear_error(tmp_path: Path) -> None:
    db = tmp_path / "ro.sqlite"
    SqliteSink(db).close()
    with Simulator(["coolpro"], seed=3) as sim:
        bus = BusConfig("b", sim.port, timeout=T, devices=[DeviceConfig("coolpro", 40)])
        sink = SqliteSink(db)
        sink.db.execute("PRAGMA query_only = 1")  # every write now fails as read-only
        with pytest.raises(OutputError, match=r"readonly|read-only|query_only"):
            Logger(LogConfig([bus], "sqlite", str(db)), sink=sink).run(10)
    con = sqlite3.connect(db)
    assert con.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    con.close()


def test_cli_exit_code_for_an_unwritable_output(tmp_path: Path) -> None:
    from pymb.cli import main

    with Simulator(["coolpro"], seed=3) as sim:
        code = main(["log", "--port", sim.port, "--device", "coolpro", "--out",
                     str(tmp_path / "no" / "such" / "dir" / "x.sqlite"), "--seconds", "1",
                     "--quiet"])
    assert code == 5  # a storage fault (the card not mounted yet?): a service retries


# -- killed at random moments -------------------------------------------------------


def sigkill_runs(n: int, tmp_path: Path, seed: int = 1) -> None:
    rng = random.Random(seed)
    db = tmp_path / "killed.sqlite"
    with Simulator(["coolpro", "hub"], seed=seed) as sim:
        before = 0
        for _ in range(n):
            proc = subprocess.Popen(
                [*PYMB, "log", "--port", sim.port, "--device",
                 "coolpro", "--device", "hub", "--out", str(db), "--quiet"], env=PYMB_ENV)
            # This run has committed (however long the start takes on this
            # machine): only then is it killed, at a random moment of its
            # commit cycle (0.5 s) or a few cycles later.
            try:
                wait_for(db, "SELECT COUNT(*) FROM samples", at_least=before + 1, proc=proc)
                time.sleep(rng.uniform(0.0, 1.2))  # the random moment: not a wait for an event
                committed = count(db, "SELECT COUNT(*) FROM samples")
                assert committed > before, (committed, before)
            finally:
                proc.send_signal(signal.SIGKILL)
                proc.wait(10)
            con = sqlite3.connect(db)
            assert con.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
            after = con.execute("SELECT COUNT(*) FROM samples").fetchone()[0]
            hub_rows = con.execute("SELECT COUNT(*) FROM hub").fetchone()[0]
            hub_samples = con.execute(
                "SELECT COUNT(*) FROM samples s JOIN devices d ON d.id = s.device_id "
                "WHERE d.type = 'hub'").fetchone()[0]
            con.close()
            assert after >= committed >= before  # nothing committed was lost
            assert hub_rows == 100 * hub_samples  # no half-written sample
            before = after


def test_sigkill_a_few_times(tmp_path: Path) -> None:
    sigkill_runs(5, tmp_path)


@pytest.mark.slow
def test_sigkill_100_times(tmp_path: Path) -> None:
    sigkill_runs(100, tmp_path, seed=7)


def test_the_stop_signal_handler_never_waits_for_a_lock(tmp_path: Path) -> None:
    """SIGTERM may arrive while the main thread, in ``Event.wait()``, holds the
    stop event's lock for a moment: a handler that took that lock would wait
    for its own thread for ever (the logger then ignored SIGTERM until it was
    killed). The handler only sets a flag, which the run loop honours."""
    bus = BusConfig("b", "/dev/null", timeout=T, devices=[DeviceConfig("coolpro", 40)])
    logger = Logger(LogConfig([bus], "sqlite", str(tmp_path / "s.sqlite")))
    with logger._signals():
        handler = signal.getsignal(signal.SIGTERM)
        assert callable(handler)
        with logger._stop._cond:  # type: ignore[attr-defined]  # the lock Event.wait() holds
            t = threading.Thread(target=handler, args=(signal.SIGTERM, None))
            t.start()
            t.join(2.0)
            done = not t.is_alive()
        t.join()
    assert done, "the SIGTERM handler waited for the stop event's lock"
    assert logger.run(30).elapsed < 25  # the run sees the flag and ends at once
