"""``pymb.client.LineListener`` (the receive loop of ``pymb scan``) on a
line whose descriptor is above 1023, in a process with more than 1024
descriptors open: it waits with poll (select() raised ValueError there)."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

from conftest import PYMB_ENV

SCRIPT = textwrap.dedent(f"""
    import os, resource, sys, time
    sys.path.insert(0, {str(Path(__file__).resolve().parents[1])!r})
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if hard != resource.RLIM_INFINITY and hard < 1300:
        print("skip: RLIMIT_NOFILE hard limit", hard); sys.exit(0)
    resource.setrlimit(resource.RLIMIT_NOFILE, (max(soft, 1300), hard))
    held = [os.open("/dev/null", os.O_RDONLY) for _ in range(1100)]
    import pymb
    from peers import PtyPeer
    from pymb.client import LineListener
    with PtyPeer(slaves={{3, 9}}) as peer, pymb.RtuClient(peer.port, 115200, slave=3) as c:
        assert c.fileno() >= 1024, c.fileno()
        line = LineListener(c.fileno(), c.baudrate, 10)
        for address in (3, 5, 9):
            line.send(address, 3, bytes((0, 1, 0, 1)))
        line.listen(time.monotonic() + 0.5)
        print(sorted(line.heard))
""")


def test_a_listener_on_a_descriptor_above_1023_hears_the_line() -> None:
    r = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True,
                       timeout=60, env=PYMB_ENV)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() in ("[3, 9]",) or r.stdout.startswith("skip"), r.stdout
