"""``pymb write`` as a user runs it, in its own process, against peers that
are not pymb: the scripted peer that logs every request and can acknowledge
a write without applying it (Modbus TCP, and RTU on a real pseudo-terminal),
pymodbus's server (TCP, RTU over TCP) and Debian's libmodbus (TCP, RTU on a
pty). Output lines ``POINT: BEFORE -> AFTER UNIT``; exit codes 0/2/3/4;
``--dry-run`` and every refusal send no byte."""

from __future__ import annotations

import signal
import socket
import struct
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import PYMB, PYMB_ENV, run_pymb
from wire_peers import build_libmodbus_server, libmodbus_server, pymodbus_server
from write_peers import WRITE_MAP, FreezingPtyPeer, FreezingTcpPeer

import pymb
from pymb.sim import SimulatorProcess


@pytest.fixture(scope="module")
def map_file(tmp_path_factory: pytest.TempPathFactory) -> str:
    path = tmp_path_factory.mktemp("map") / "wdev.toml"
    path.write_text(WRITE_MAP.format(device="", limits="", budget=""))
    return str(path)


@pytest.fixture
def peer() -> Iterator[FreezingTcpPeer]:
    with FreezingTcpPeer() as p:
        yield p


def write(map_file: str, *args: str) -> tuple[int, str, str]:
    r = run_pymb("write", "--map", map_file, *args)
    return r.returncode, r.stdout, r.stderr


def test_write_prints_before_and_after_and_reads_back(map_file: str,
                                                      peer: FreezingTcpPeer) -> None:
    peer.memory.holding[10] = 5000
    peer.memory.holding[12] = 0
    code, out, err = write(map_file, "wdev:1", "setpoint_hz=49.5", "mode=run", "pump_on=false",
                           "zone_c_2=21.5", "--tcp", f"127.0.0.1:{peer.port}")
    assert (code, err) == (0, "")
    before_zone = (41 * 7) / 10
    assert out.splitlines() == [
        "setpoint_hz: 50 -> 49.5 Hz",
        "mode: stop -> run",
        "pump_on: false -> false",
        f"zone_c_2: {before_zone:g} -> 21.5 °C",
    ]
    assert peer.memory.holding[10] == 4950
    assert peer.memory.holding[41] == 215


def test_no_verify_reads_before_but_not_after(map_file: str, peer: FreezingTcpPeer) -> None:
    peer.memory.holding[11] = 10
    code, out, _ = write(map_file, "wdev", "power_limit_pct=80", "--no-verify",
                         "--tcp", f"127.0.0.1:{peer.port}")
    assert code == 0
    assert out == "power_limit_pct: 10 -> 80 (not read back) %\n"
    assert peer.functions() == [3, 6]


def test_not_applied_exits_3_and_says_what_the_device_holds(map_file: str,
                                                             peer: FreezingTcpPeer) -> None:
    peer.memory.holding[11] = 10
    peer.frozen.add(11)
    code, out, err = write(map_file, "wdev:1", "power_limit_pct=80", "--tcp",
                           f"127.0.0.1:{peer.port}")
    assert code == 3
    assert out == "power_limit_pct: 10 -> 10 % (not applied)\n"
    assert err == (f"pymb write: wdev:1 on 127.0.0.1:{peer.port}: not applied: "
                   "'power_limit_pct': sent 80, the device holds 10\n")


def test_a_device_exception_exits_3(map_file: str, peer: FreezingTcpPeer) -> None:
    peer.hook = lambda s, pdu, normal: [(0.0, peer.frame(s, bytes((0x86, 3))))] \
        if pdu[0] == 6 else None
    code, out, err = write(map_file, "wdev:1", "power_limit_pct=80", "--tcp",
                           f"127.0.0.1:{peer.port}")
    assert code == 3
    assert out == ""
    assert err.startswith("pymb write: ")
    assert "illegal data value" in err.lower()


def test_no_answer_exits_3(map_file: str) -> None:
    with FreezingTcpPeer(slaves={2}) as silent:
        code, _, err = write(map_file, "wdev:1", "mode=run", "--tcp",
                             f"127.0.0.1:{silent.port}", "--timeout", "0.3")
    assert code == 3, err


def test_connection_failure_exits_4(map_file: str) -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # nothing listens there
    code, out, err = write(map_file, "wdev:1", "mode=run", "--tcp", f"127.0.0.1:{port}")
    assert (code, out) == (4, "")
    assert err.startswith("pymb write: ")


@pytest.mark.parametrize(("args", "message"), [
    (["setpoint_hz=70"], "outside its valid range 45..65"),
    (["setpont_hz=50"], "did you mean 'setpoint_hz'?"),
    (["firmware=2"], "read-only"),
    (["mode=running"], "did you mean 'run'?"),
    (["relay_2=maybe"], "true or false"),
    (["setpoint_hz"], "write values as POINT=VALUE"),
    (["mode=run", "mode=stop"], "given twice"),
    (["mode=run", "setpoint_hz=99"], "outside"),  # one refused value writes nothing
])
def test_every_refusal_exits_2_and_sends_no_byte(map_file: str, peer: FreezingTcpPeer,
                                                 args: list[str], message: str) -> None:
    code, out, err = write(map_file, "wdev:1", *args, "--tcp", f"127.0.0.1:{peer.port}")
    assert (code, out) == (2, "")
    assert message in err
    assert err.count("\n") == 1
    assert "Traceback" not in err
    assert peer.requests == []


def test_a_name_close_to_nothing_lists_the_writable_points(map_file: str) -> None:
    """No guess: the points a write may name, a block as its channels' range,
    not every point of the map (a hub's 700 read-only channels)."""
    code, out, err = write(map_file, "wdev:1", "speed=3", "--tcp", "127.0.0.1:1", "--dry-run")
    assert (code, out) == (2, "")
    assert err == ("pymb write: wdev: no point 'speed'; writable: fan_on, level, mode, "
                   "power_limit_pct, pump_on, relay_2, relay_5, reset, setpoint_hz, "
                   "status, target_w, zone_c_1..zone_c_4\n")
    r = run_pymb("write", "hub:1", "speed=3", "--tcp", "127.0.0.1:1", "--dry-run")
    assert (r.returncode, r.stdout, r.stderr) == (
        2, "", "pymb write: hub: no point 'speed'; it has no writable point\n")


@pytest.mark.ctrl_c
def test_ctrl_c_once_the_line_is_open_says_the_value_may_be_written(map_file: str) -> None:
    """Ctrl-C while the device is silent: exit 130 and one line saying the
    points may or may not have been written, not a silence that leaves the
    user guessing what the device holds."""
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen(1)
        server.settimeout(60)
        proc = subprocess.Popen(
            [*PYMB, "write", "--map", map_file, "wdev:1", "setpoint_hz=49.5", "mode=run",
             "--tcp", f"127.0.0.1:{server.getsockname()[1]}", "--timeout", "30"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=PYMB_ENV)
        conn, _ = server.accept()  # the line is open; the device answers nothing
        with conn:
            assert conn.recv(260)  # the read before the write
            proc.send_signal(signal.SIGINT)
            out, err = proc.communicate(timeout=30)
    assert (proc.returncode, out) == (130, "")
    assert err == ("pymb write: interrupted; setpoint_hz, mode may or may not have been "
                   "written: read them to know\n")


def test_a_value_of_the_wrong_kind_is_named_by_its_device(map_file: str) -> None:
    """As every other refusal of a value: 'wdev: point ...'."""
    for value, said in (("relay_2=maybe", "point 'relay_2': true or false is needed, got "
                                          "'maybe'"),
                        ("setpoint_hz=fast", "point 'setpoint_hz': a number is needed, got "
                                             "'fast'")):
        code, out, err = write(map_file, "wdev:1", value, "--tcp", "127.0.0.1:1", "--dry-run")
        assert (code, out, err) == (2, "", f"pymb write: wdev: {said}\n")


def test_a_dry_run_needs_no_network(map_file: str) -> None:
    """--dry-run opens no line, so a host name that does not resolve here (a
    plan made away from the plant's network) does not stop it; a write does."""
    for where in ("--tcp", "--udp"):
        code, out, err = write(map_file, "wdev:1", "mode=run", where, "plant-gw.invalid:502",
                               "--dry-run")
        assert (code, out, err) == (0, "FC 06 holding 12: 0x0001 (mode)\n", "")
    code, out, err = write(map_file, "wdev:1", "mode=run", "--tcp", "plant-gw.invalid:502")
    assert (code, out) == (4, "")
    assert err.startswith("pymb write: cannot connect to plant-gw.invalid:502: ")


def test_unknown_device_type_exits_2(map_file: str) -> None:
    code, _, err = write(map_file, "wdevv:1", "mode=run", "--tcp", "127.0.0.1:1")
    assert code == 2
    assert "unknown device" in err
    assert "did you mean" in err


def test_dry_run_prints_the_requests_and_sends_nothing(map_file: str,
                                                       peer: FreezingTcpPeer) -> None:
    code, out, err = write(map_file, "wdev:1", "setpoint_hz=49.5", "power_limit_pct=80",
                           "relay_2=true", "pump_on=1", "fan_on=1", "--dry-run",
                           "--tcp", f"127.0.0.1:{peer.port}")
    assert (code, err) == (0, "")
    assert out.splitlines() == [
        "FC 15 coil 5: 1 1 (pump_on, fan_on)",
        "FC 16 holding 10: 0x1356 0x0050 (setpoint_hz, power_limit_pct)",
        "FC 06 holding 20: read (FC 03), then 0x0004 with the other bits as read (relay_2)",
    ]
    assert peer.requests == []


def test_rtu_on_a_pty(map_file: str) -> None:
    with FreezingPtyPeer() as peer:
        peer.memory.holding[20] = 0x0001
        code, out, err = write(map_file, "wdev:1", "relay_5=on", "--port", peer.port,
                               "--baud", "19200")
        assert (code, err) == (0, "")
        assert out == "relay_5: false -> true\n"
        assert peer.memory.holding[20] == 0x0021
        assert peer.functions() == [3, 6, 3]  # read, changed and written back, read back


@pytest.mark.parametrize("mode", ["tcp", "rtu-over-tcp"])
def test_against_pymodbus(map_file: str, mode: str) -> None:
    pytest.importorskip("pymodbus")
    with pymodbus_server(mode) as port:
        code, out, err = write(map_file, "wdev:1", "setpoint_hz=49.5", "target_w=-12.25",
                               "fan_on=true", "level=200", f"--{mode}", f"127.0.0.1:{port}")
        assert (code, err) == (0, ""), out
        # the f32 before is 9.000025759821893e-39: the fewest digits that give it back
        assert _f32(7 * 14, 7 * 15) == struct.unpack(">f", struct.pack(">f", 9.000026e-39))[0]
        assert out.splitlines()[:2] == ["setpoint_hz: 0.7 -> 49.5 Hz",
                                        "target_w: 9.000026e-39 -> -12.25 W"]
        cls = pymb.TcpClient if mode == "tcp" else pymb.RtuOverTcpClient
        with cls("127.0.0.1", port, timeout=2.0) as c:
            assert list(c.read_holding_registers(10, 1, slave=1)) == [4950]
            assert list(c.read_holding_registers(21, 1, slave=1)) == [(7 * 21) & 0xFF00 | 200]


def _f32(hi: int, lo: int) -> float:
    value: float = struct.unpack(">f", struct.pack(">HH", hi, lo))[0]
    return value


@pytest.fixture(scope="module")
def libmodbus_exe(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return build_libmodbus_server(tmp_path_factory.mktemp("libmodbus"))


@pytest.mark.parametrize("mode", ["tcp", "rtu"])
def test_against_libmodbus(map_file: str, libmodbus_exe: Path, mode: str) -> None:
    with libmodbus_server(libmodbus_exe, mode) as where:
        line = ["--tcp", f"127.0.0.1:{where}"] if mode == "tcp" else ["--port", where]
        code, out, err = write(map_file, "wdev:17", "power_limit_pct=42", "relay_2=true",
                               "zone_c_1=7.5", *line)
        assert (code, err) == (0, ""), out
        assert out.splitlines() == ["power_limit_pct: 33 -> 42 %",
                                    "relay_2: true -> true" if (60 >> 2) & 1 else
                                    "relay_2: false -> true",
                                    "zone_c_1: 12 -> 7.5 °C"]


def test_an_allow_list_in_the_file_that_matches_nothing_says_what_may_be_allowed(
        map_file: str, tmp_path: Path) -> None:
    """The patterns of the file's [writes] are not called options the user did
    not type, and the line lists the DEVICE/POINT names that are writable."""
    config = tmp_path / "log.toml"
    config.write_text(f"""maps = [{map_file!r}]
[output]
path = "x.sqlite"
[[bus]]
name = "b"
tcp = "127.0.0.1:1"
  [[bus.device]]
  type = "wdev"
  name = "psu-a"
[mqtt]
url = "mqtt://127.0.0.1:1"
[writes]
allow = ["psu-b/setpoint_hz"]
""")
    r = run_pymb("log", "--config", str(config), "--seconds", "1", cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    assert r.stderr.splitlines()[-1] == (
        "pymb log: --allow-writes ([writes] allow) psu-b/setpoint_hz: no writable point of a "
        "logged device matches (DEVICE/POINT, the device's name); writable: psu-a/fan_on, "
        "psu-a/level, psu-a/mode, psu-a/power_limit_pct, psu-a/pump_on, psu-a/relay_2, "
        "psu-a/relay_5, psu-a/reset, psu-a/setpoint_hz, psu-a/status, ...")
    assert "Traceback" not in r.stderr


@pytest.mark.parametrize(("extra", "message"), [
    (["--allow-writes", "psu-a/setpoint_hz"], "needs --mqtt URL"),
    (["--allow-writes", "setpoint_hz", "--mqtt", "mqtt://127.0.0.1:1"], "DEVICE/POINT"),
    (["--allow-writes", "psu-a/nothing_*", "--mqtt", "mqtt://127.0.0.1:1"],
     "no writable point of a logged device matches"),
])
def test_log_allow_writes_mistakes_exit_2(map_file: str, tmp_path: Path, extra: list[str],
                                          message: str) -> None:
    r = run_pymb("log", "--map", map_file, "--tcp", "127.0.0.1:1", "--device",
                 "wdev:1,name=psu-a", "--out", str(tmp_path / "x.sqlite"), "--seconds", "1",
                 *extra)
    assert r.returncode == 2, r.stderr
    assert message in r.stderr
    assert "Traceback" not in r.stderr


def test_the_coolpros_reset_reads_0_so_it_is_not_applied_unless_not_verified() -> None:
    # docs/writes.md: a command register that never reads back what was written
    with SimulatorProcess(["coolpro"], quiet=True) as sim:
        r = run_pymb("write", "coolpro", "reset=0xAA55", "--port", sim.port)
        assert (r.returncode, r.stdout) == (3, "reset: 0 -> 0 (not applied)\n")
        assert "not applied: 'reset': sent 43605, the device holds 0" in r.stderr
        r = run_pymb("write", "coolpro", "reset=0xAA55", "--no-verify", "--port", sim.port)
        assert (r.returncode, r.stdout, r.stderr) == (0, "reset: 0 -> 43605 (not read back)\n",
                                                      "")


def test_before_and_after_keep_every_digit_of_the_value(map_file: str,
                                                         peer: FreezingTcpPeer) -> None:
    peer.memory.holding[14:16] = [0x3FC0, 0x0000]   # f32 1.5
    code, out, err = write(map_file, "wdev:1", "target_w=123456.78", "setpoint_hz=49.99",
                           "--tcp", f"127.0.0.1:{peer.port}")
    assert (code, err) == (0, "")
    # the f32 read back is 123456.78125: its own digits, not 6 significant ones (123457)
    assert out.splitlines() == ["target_w: 1.5 -> 123456.78 W", "setpoint_hz: 0.7 -> 49.99 Hz"]
