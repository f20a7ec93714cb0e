"""``pymb simulate --tcp`` on many ports: the same devices answer on each port of
a range, or on ``--count N`` free ports, as N TCP devices on one network; the
endpoint line names every port; mistakes are one line."""

from __future__ import annotations

import signal
import subprocess

import pytest
from conftest import PYMB, PYMB_ENV, run_pymb

from pymb import TcpClient
from pymb.sim import Simulator
from pymb.sim.tcp import format_ports, parse_ports


def test_count_free_ports_each_answer_at_once() -> None:
    proc = subprocess.Popen([*PYMB, "simulate", "eastron-sdm630:7", "--tcp", "127.0.0.1:0",
                             "--count", "12"], stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, text=True, env=PYMB_ENV)
    try:
        assert proc.stdout is not None
        host, _, ports_text = proc.stdout.readline().strip().rpartition(":")
        ports = parse_ports(ports_text)
        assert host == "127.0.0.1"
        assert len(set(ports)) == 12
        assert 0 not in ports
        clients = [TcpClient(host, p, slave=7, timeout=5.0) for p in ports]
        try:
            for c in clients:  # every connection open at once, as a gateway's master holds them
                c.connect()
            first = [list(c.read_input_registers(0, 2)) for c in clients]
            assert all(r == first[0] for r in first)  # one device model behind every port
            assert first[0] != [0, 0]  # the map's voltage, not an empty image
        finally:
            for c in clients:
                c.close()
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=30)
    assert proc.returncode == 0


def test_a_range_is_served_port_by_port() -> None:
    with Simulator(["coolpro:40"], transport="tcp", tcp_ports=[0, 0, 0]) as sim:
        ports = sim.tcp_ports
        assert sim.endpoint == f"127.0.0.1:{format_ports(ports)}"
    first = ports[0]
    # the same three ports again, as a range: the listeners were closed and the range is free
    wanted = list(range(first, first + 3))
    try:
        sim = Simulator(["coolpro:40"], transport="tcp", tcp_ports=wanted).start()
    except OSError:
        pytest.skip("the ports after a free one are taken on this machine")
    try:
        assert sim.endpoint == f"127.0.0.1:{first}-{first + 2}"
        for p in wanted:
            with TcpClient("127.0.0.1", p, slave=40, timeout=5.0) as c:
                assert len(c.read_input_registers(0, 8)) == 8
    finally:
        sim.stop()


def test_port_lists_parse_and_print() -> None:
    assert parse_ports("5020-5023") == [5020, 5021, 5022, 5023]
    assert parse_ports("7,9") == [7, 9]
    assert format_ports([5020, 5021, 5022]) == "5020-5022"
    assert format_ports([7, 9]) == "7,9"
    assert format_ports([502]) == "502"


@pytest.mark.parametrize(("argv", "message"), [
    (["--tcp", "127.0.0.1:5030-5020"], "bad port or port range"),
    (["--tcp", "127.0.0.1:5020-x"], "bad port or port range"),
    (["--tcp", "127.0.0.1:1-2000"], "at most 1000"),
    (["--tcp", "5020-5021", "--count", "2"], "not both"),
    (["--tcp", "65535", "--count", "2"], "past port 65535"),
    (["--tcp", "0", "--count", "0"], "--count must be 1..1000"),
    (["--count", "3"], "--count is for --tcp only"),
])
def test_mistakes_are_one_line(argv: list[str], message: str) -> None:
    done = run_pymb("simulate", "coolpro", *argv, timeout=60)
    assert done.returncode != 0
    assert message in done.stderr
    assert "Traceback" not in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1, done.stderr
