"""Independent masters against the simulators (Debian's mbpoll, pymodbus),
Modbus TCP, the ``pymb simulate`` command and the child-process API."""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from conftest import PYMB, PYMB_ENV, run_pymb

import pymb
from pymb.sim import CoolProDevice, HubDevice, Simulator, SimulatorProcess

pytest_plugins = ["pymb.testing"]

MakeSim = Callable[..., Simulator]
MBPOLL = shutil.which("mbpoll")
needs_mbpoll = pytest.mark.skipif(MBPOLL is None, reason="mbpoll is not installed "
                                  "(Debian package mbpoll; CI installs it)")


def mbpoll(*args: str) -> tuple[int, list[int], str]:
    """Run mbpoll once; its exit code, the values it printed, all its output."""
    assert MBPOLL is not None
    p = subprocess.run([MBPOLL, "-1", *args], capture_output=True, text=True, timeout=20,
                       check=False)
    values = [int(v) for v in re.findall(r"^\[\d+\]:\s+(-?\d+)", p.stdout, re.M)]
    return p.returncode, values, p.stdout + p.stderr


# -- mbpoll ---------------------------------------------------------------------------


@needs_mbpoll
def test_mbpoll_reads_coolpro_telemetry_and_identity(coolpro_sim: Simulator) -> None:
    rtu = ["-m", "rtu", "-a", "40", "-b", "9600", "-P", "none", "-o", "0.5"]
    rc, v, out = mbpoll(*rtu, "-t", "3", "-r", "1", "-c", "8", coolpro_sim.port)
    assert rc == 0, out
    vin, _iin, vout, _iout, temp, _up_lo, _up_hi, _status = v
    assert 24_000 < vin < 25_000
    assert 23_800 < vout < 24_200
    assert 0 < temp <= 65_535
    rc, v, out = mbpoll(*rtu, "-t", "3", "-0", "-r", "100", "-c", "8", coolpro_sim.port)
    assert rc == 0, out
    assert v[0] | v[1] << 16 == 12345
    assert v[3:6] == [1, 0, 0]


@needs_mbpoll
def test_mbpoll_writes_coolpro_configuration(coolpro_sim: Simulator) -> None:
    rtu = ["-m", "rtu", "-a", "40", "-b", "9600", "-P", "none", "-o", "0.5", "-t", "4"]
    rc, _, out = mbpoll(*rtu, "-r", "1", coolpro_sim.port, "42")
    assert rc == 0, out
    rc, _, out = mbpoll(*rtu, "-r", "2", coolpro_sim.port, "3")
    assert rc == 0, out
    rc, v, out = mbpoll(*rtu, "-r", "1", "-c", "3", coolpro_sim.port)
    assert (rc, v) == (0, [42, 3, 0]), out
    rc, _, out = mbpoll(*rtu, "-r", "3", coolpro_sim.port, "1")  # not 0xAA55
    assert rc != 0
    assert "Illegal data value" in out
    rc, _, out = mbpoll(*rtu, "-r", "3", coolpro_sim.port, str(0xAA55))
    assert rc == 0, out
    cp = coolpro_sim.devices[0]
    assert isinstance(cp, CoolProDevice)
    assert (cp.address, cp.baud) == (42, 57600)


@needs_mbpoll
def test_mbpoll_over_tcp(pymb_simulator: MakeSim) -> None:
    sim = pymb_simulator("hub:250", transport="tcp")
    rc, v, out = mbpoll("-m", "tcp", "-p", str(sim.tcp_port), "-a", "250", "-t", "4", "-0",
                        "-r", "31", "-c", "10", "-o", "0.5", sim.host)
    assert rc == 0, out
    assert len(v) == 10, out


# -- pymodbus -------------------------------------------------------------------------


def test_pymodbus_reads_a_hub_block(pymb_simulator: MakeSim) -> None:
    serial_client = pytest.importorskip("pymodbus.client").ModbusSerialClient
    sim = pymb_simulator("hub", "hub:250,firmware=1.07")
    hub = sim.device(1)
    assert isinstance(hub, HubDevice)
    # the values follow the simulated clock (and refresh whenever the line is
    # quiet for 0.25 s): held still, the image read afterwards is the one served
    sim.clock.freeze()
    hub.pin("temperature_c", 1, 0x80C8)  # -20.0 °C
    client = serial_client(sim.port, baudrate=9600, timeout=1, retries=0)
    assert client.connect()
    try:
        rr = client.read_holding_registers(31, count=125, device_id=1)
        assert not rr.isError()
        assert len(rr.registers) == 125
        assert rr.registers[0] == 0x80C8
        assert list(rr.registers) == list(hub.registers(31, 125))
        rr = client.read_holding_registers(231, count=10, device_id=250)  # 1.07: no block
        assert rr.isError()
        assert rr.exception_code == 2
    finally:
        client.close()


# -- Modbus TCP ----------------------------------------------------------------------


def test_tcp_with_pymb_and_faults(pymb_simulator: MakeSim) -> None:
    sim = pymb_simulator("coolpro", "hub:250", transport="tcp")
    assert sim.host == "127.0.0.1"
    assert sim.endpoint == f"127.0.0.1:{sim.tcp_port}"
    f = sim.faults
    with pymb.TcpClient(sim.host, sim.tcp_port, slave=40, timeout=0.2) as c:
        assert len(c.read_input_registers(0, 8)) == 8
        assert len(c.read_holding_registers(31, 700, slave=250)) == 700
        with pytest.raises(pymb.IllegalFunction):
            c.write_registers(31, [1], slave=250)
        with pytest.raises(pymb.ModbusTimeout):
            c.read_input_registers(0, 1, slave=41)  # nobody there
        f.inject("no_reply")
        with pytest.raises(pymb.ModbusTimeout):
            c.read_input_registers(0, 1)
        f.inject("wrong_address")
        with pytest.raises(pymb.ProtocolError):
            c.read_input_registers(0, 1)
        f.inject("busy", address=250)
        with pytest.raises(pymb.DeviceException) as e:
            c.read_holding_registers(31, 1, slave=250)
        assert e.value.code == 4
        f.inject("bad_crc")  # no CRC on TCP: not applied, the request is answered
        assert len(c.read_input_registers(0, 1)) == 1
        assert f.counts["bad_crc"] == 0
        assert f.pending == 1
        f.clear()
        sim.unplug()
        with pytest.raises(pymb.ModbusConnectionError):
            c.read_input_registers(0, 1)
        sim.replug()
        for _ in range(2):
            try:
                c.read_input_registers(0, 1)
                break
            except pymb.ModbusConnectionError:
                continue
        assert len(c.read_input_registers(0, 8)) == 8


# -- the command line ----------------------------------------------------------------


def _start(*args: str) -> tuple[subprocess.Popen[str], str]:
    p = subprocess.Popen([*PYMB, "simulate", *args], text=True,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=PYMB_ENV)
    assert p.stdout is not None
    line = p.stdout.readline().strip()
    return p, line


def _stop(p: subprocess.Popen[str], sig: int = signal.SIGTERM) -> tuple[int, str]:
    p.send_signal(sig)
    try:
        _, err = p.communicate(timeout=10)
    finally:
        if p.poll() is None:
            p.kill()
    return p.returncode, err


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
@pytest.mark.ctrl_c
def test_cli_prints_the_pty_first_and_stops_cleanly(sig: int) -> None:
    p, path = _start("coolpro", "hub")
    try:
        assert re.fullmatch(r"/dev/pts/\d+", path), path
        with pymb.RtuClient(path, 9600, slave=40, timeout=1) as c:
            assert len(c.read_input_registers(0, 8)) == 8
            assert len(c.read_holding_registers(31, 125, slave=1)) == 125
    finally:
        rc, err = _stop(p, sig)
    assert rc == 0, err
    assert "coolpro at address 40" in err
    assert "hub at address 1" in err


def test_cli_tcp_link_faults_and_errors(tmp_path: Path) -> None:
    p, endpoint = _start("coolpro:41", "--tcp", "127.0.0.1:0", "--fault", "exception,code=3")
    try:
        host, port = endpoint.rsplit(":", 1)
        assert host == "127.0.0.1"
        with pymb.TcpClient(host, int(port), slave=41, timeout=1) as c, \
                pytest.raises(pymb.IllegalDataValue):
            c.read_input_registers(0, 1)
    finally:
        rc, err = _stop(p)
    assert rc == 0, err
    assert "'exception': 1" in err, err

    link = tmp_path / "ttyCP"
    p, printed = _start("coolpro", "--link", str(link), "--baud", "19200")
    try:
        assert printed == str(link)
        assert os.path.islink(link)
        with pymb.RtuClient(printed, 19200, slave=40, timeout=1) as c:
            assert len(c.read_input_registers(0, 8)) == 8
    finally:
        rc, err = _stop(p)
    assert rc == 0, err
    assert not os.path.exists(link), err

    bad = run_pymb("simulate", "toaster", timeout=20)
    assert bad.returncode == 2
    assert "unknown device" in bad.stderr
    bad = run_pymb("simulate", "--port", "/nonexistent", timeout=20)
    assert bad.returncode == 4
    assert "/nonexistent" in bad.stderr


def test_simulator_process_for_benchmarks() -> None:
    with SimulatorProcess(["hub", "--tcp", "127.0.0.1:0"]) as proc, \
            pymb.TcpClient(proc.host, proc.tcp_port, slave=1, timeout=1) as c:
        t = time.perf_counter()
        for _ in range(20):
            c.read_holding_registers(31, 700)
        assert time.perf_counter() - t < 5
    with SimulatorProcess(["coolpro"]) as proc, \
            pymb.RtuClient(proc.port, 9600, slave=40, timeout=1) as c:
        assert len(c.read_input_registers(100, 8)) == 8


# -- the pytest fixtures --------------------------------------------------------------


def test_fixtures(coolpro_sim: Simulator, hub_sim: Simulator,
                  pymb_simulator: MakeSim) -> None:
    assert coolpro_sim.devices[0].address == 40
    assert hub_sim.devices[0].address == 1
    other = pymb_simulator("hub:9", transport="tcp", seed=5)
    assert other.device(9).kind == "hub"
    assert os.path.exists(coolpro_sim.port)
