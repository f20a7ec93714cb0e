"""Shell examples of the guides that talk to programs other than pymb run as
a user runs them: docs/simulators.md's ``mbpoll`` against ``pymb simulate``
(an independent master reading the simulated CoolPro), and docs/fleet.md's
``mosquitto_sub`` watching ``pymb log --mqtt`` (Debian's broker on a free
port in place of localhost:1883); and docs/board.md's line for a new MQTT
cursor with a month of samples to send, as ``pymb log --mqtt`` prints it."""

from __future__ import annotations

import re
import shlex
import subprocess
import time
from array import array
from collections.abc import Callable
from pathlib import Path

import reference as ref
from clikit import Pty
from conftest import run_pymb
from docblocks import assert_shaped, claim_one

from pymb.devices import CoolProStatus, CoolProTelemetry
from pymb.fleet.broker import Mosquitto
from pymb.sim import Simulator, SimulatorProcess
from pymb.store import DeviceInfo, Sample, SqliteSink

pytest_plugins = ["mqtt_broker"]  # the mosquitto fixture


def _commands(text: str) -> list[list[str]]:
    """The commands of a shell block, comments and a trailing ``&`` dropped."""
    return [shlex.split(line.removesuffix("&").strip()) for line in
            (re.sub(r"(^|\s)#.*", "", raw).strip() for raw in text.splitlines()) if line]


def test_mbpoll_reads_the_simulated_coolpro() -> None:
    block = claim_one("docs/simulators.md", "sh", how="run")
    simulate, mbpoll = _commands(block.text)
    assert simulate[:2] == ["pymb", "simulate"]
    assert mbpoll[0] == "mbpoll"
    with SimulatorProcess(simulate[2:], quiet=True) as sim:
        assert sim.endpoint.startswith("/dev/")  # it printed the pty path
        argv = [sim.endpoint if a.startswith("/dev/pts/") else a for a in mbpoll]
        r = subprocess.run(argv, capture_output=True, text=True, timeout=60, check=False)
    assert r.returncode == 0, r.stdout + r.stderr
    values = re.findall(r"^\[(\d+)\]:\s+(-?\d+)", r.stdout, re.M)
    assert [int(n) for n, _ in values] == list(range(1, 9)), r.stdout  # input registers 0..7
    assert int(values[0][1]) > 20000  # the input voltage, in mV


def test_mosquitto_sub_watches_pymb_log(mosquitto: Callable[..., Mosquitto],
                                        tmp_path: Path) -> None:
    block = claim_one("docs/fleet.md", "sh", how="run", contains="mosquitto_sub")
    commands = _commands(block.text)
    assert commands[0][:2] == ["apt-get", "install"]  # .ci/setup installs them
    sub_argv, log_argv = commands[1], commands[2]
    assert sub_argv[0] == "mosquitto_sub"
    assert log_argv[:2] == ["pymb", "log"]
    broker = mosquitto()
    port = str(broker.port)
    # at most 3 messages, at most 30 s
    sub = subprocess.Popen([*sub_argv, "-h", "127.0.0.1", "-p", port, "-C", "3", "-W", "30"],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        with Simulator(["hub:250"], seed=5) as sim:
            args = [sim.port if a == "/dev/ttyUSB0" else
                    f"mqtt://127.0.0.1:{port}" if a == "mqtt://localhost" else a
                    for a in log_argv[1:]]
            r = run_pymb(*args, "--seconds", "2", cwd=tmp_path, timeout=120)
        out, err = sub.communicate(timeout=60)
    finally:
        if sub.poll() is None:
            sub.kill()
            sub.communicate(timeout=10)
    assert r.returncode == 0, r.stderr
    assert sub.returncode == 0, err
    topics = [line.split(" ", 1)[0] for line in out.splitlines()]
    assert len(topics) == 3, out
    assert all(t.startswith("pymb/") for t in topics), topics
    assert any(t.endswith("/hub-250") for t in topics), topics
    assert (tmp_path / "plant.sqlite").exists()


def test_the_new_cursor_notice_is_what_pymb_log_says(mosquitto: Callable[..., Mosquitto],
                                                     tmp_path: Path) -> None:
    """docs/board.md's line for a new MQTT cursor with more than a day of
    samples to send: a database whose oldest sample is 30 days old, logged
    to with --mqtt towards a broker it has never sent to."""
    block = claim_one("docs/board.md", "text", how="compare", contains="a new MQTT cursor")
    db = tmp_path / "data.sqlite"
    regs = array("H", [24000, 1000, 12000, 500, 30000, 7, 0, 1])
    vin, iin, vout, iout, temp, up, status = ref.coolpro_telemetry(list(regs))
    old = CoolProTelemetry(vin, iin, vout, iout, temp, up, CoolProStatus(status), regs)
    sink = SqliteSink(db)
    month = time.time() - 30 * 86400
    info = DeviceInfo("bus1", "127.0.0.1:502", "coolpro", 40, "coolpro-40")
    for i in range(3):
        sink.write(Sample(info, month + i, float(i), old))
    sink.close()
    broker = mosquitto()
    with SimulatorProcess(["coolpro", "--tcp", "127.0.0.1:0"], quiet=True) as sim:
        r = run_pymb("log", "coolpro:40", "--tcp", sim.endpoint, "--out", str(db), "--mqtt",
                     f"mqtt://127.0.0.1:{broker.port}", "--mqtt-node", "board-7",
                     "--seconds", "1", "--quiet", timeout=120)
    assert r.returncode == 0, r.stderr
    lines = [line for line in r.stderr.splitlines() if "a new MQTT cursor" in line]
    assert len(lines) == 1, r.stderr
    assert_shaped(block, lines)
    assert "(30.0 days)" in lines[0]


def test_the_status_line_with_a_broker(mosquitto: Callable[..., Mosquitto],
                                       tmp_path: Path) -> None:
    """docs/fleet.md's status line of ``pymb log --mqtt``, as a terminal shows
    it: a run on a pseudo-terminal 120 columns wide, once the broker has
    acknowledged something."""
    block = claim_one("docs/fleet.md", "text", how="compare", contains="mqtt ok")
    broker = mosquitto()
    with SimulatorProcess(["coolpro", "--tcp", "127.0.0.1:0"], quiet=True) as sim:
        term = Pty(["log", "coolpro:40", "--tcp", sim.endpoint, "--out",
                    str(tmp_path / "s.sqlite"), "--mqtt", f"mqtt://127.0.0.1:{broker.port}"],
                   cols=120)
        try:
            # the status line is redrawn twice a second: wait for one with an ack
            # and, as the page shows, a backlog with no age (a loaded machine can
            # hold a backlog over a second old for a while)
            acked = re.compile(rb"samples .* backlog \d+ last ack \d")
            for _ in range(60):
                if acked.search(term.out) or not term.read_more(b"last ack", 1, 10):
                    break
            assert acked.search(term.out), term.out[-500:]
        finally:
            term.interrupt()
    drawn = re.split(r"\r|\n|\x1b\[K", term.out.decode(errors="replace"))
    lines = [line for line in drawn if re.search(r"samples .* backlog \d+ last ack \d", line)]
    assert lines, term.out[-500:]
    assert_shaped(block, lines[-1:])
