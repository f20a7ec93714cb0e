"""A simulator started in a process that has more than 1024 descriptors open
(a test harness, a gateway that polls hundreds of devices) serves as any
other: its waits use poll, not select(), which fails above descriptor 1023.
Each case runs in a process of its own, its descriptor limit raised."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

from conftest import PYMB_ENV

HEAD = f"""
import os, resource, socket, struct, sys, time
sys.path.insert(0, {str(Path(__file__).resolve().parents[1])!r})
soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
if hard != resource.RLIM_INFINITY and hard < 1300:
    print("skip: RLIMIT_NOFILE hard limit", hard); sys.exit(0)
resource.setrlimit(resource.RLIMIT_NOFILE, (max(soft, 1300), hard))
held = [os.open("/dev/null", os.O_RDONLY) for _ in range(1100)]
import pymb
from pymb.sim import Simulator
from servekit import RawClient
"""


def run(body: str) -> str:
    r = subprocess.run([sys.executable, "-c", HEAD + textwrap.dedent(body)],
                       capture_output=True, text=True, timeout=60, env=PYMB_ENV)
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr, r.stderr
    return r.stdout.strip()


def test_a_pty_simulator_answers_and_comes_back_after_an_unplug() -> None:
    out = run("""
        with Simulator(["coolpro"]) as sim:
            with pymb.RtuClient(sim.port, 9600, slave=40, timeout=1) as c:
                assert c.fileno() >= 1024, c.fileno()
                print(c.read_input_registers(100, 1)[0])
            sim.unplug(seconds=0.3)
            time.sleep(0.6)
            with pymb.RtuClient(sim.port, 9600, slave=40, timeout=1) as c:
                print(c.read_input_registers(100, 1)[0])
    """)
    assert out.startswith("skip") or out.split() == ["12345", "12345"], out


def test_a_tcp_client_that_never_reads_is_dropped_and_the_others_are_served() -> None:
    # Once the kernel holds all it takes of the replies to a client that
    # never reads, the simulator waits for room with poll, and after a second
    # drops that client (select() raised ValueError in the simulator's
    # thread instead, which then served no one).
    out = run("""
        with Simulator(["hub:1,delay=0"], transport="tcp") as sim:
            greedy = socket.socket()
            greedy.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
            greedy.connect(("127.0.0.1", sim.tcp_port))
            assert greedy.fileno() >= 1024
            ask = struct.pack(">HHHBBHH", 1, 0, 6, 1, 3, 31, 125)  # 259-byte replies
            greedy.settimeout(10)
            try:
                for _ in range(30000):
                    greedy.sendall(ask)
            except OSError:
                pass  # dropped while it still sent
            time.sleep(3)  # the replies fill the kernel's buffers: the wait, the drop
            c = RawClient(sim.tcp_port, timeout=10)
            print(c.ask(9, 1, struct.pack(">BHH", 3, 31, 1)).hex())
            c.close()
            greedy.close()
    """)
    assert out.startswith("skip") or out.startswith("0302"), out
