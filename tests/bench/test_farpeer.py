"""The serve section's far device (``python -m pymb.bench.farpeer``), a real
process on loopback: a header the MBAP length rule refuses closes the
connection, with nothing on its stderr ([MB-AP] 4.1: protocol id 0)."""

from __future__ import annotations

import socket
import subprocess
import sys


def test_a_refused_header_closes_the_connection_without_a_traceback() -> None:
    p = subprocess.Popen([sys.executable, "-m", "pymb.bench.farpeer", "0.001"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert p.stdout is not None
        port = int(p.stdout.readline())
        with socket.create_connection(("127.0.0.1", port), timeout=10) as s:
            s.sendall(bytes.fromhex("0001 0000 0006 01 03 0000 0001"))  # a good request
            assert s.recv(64) == bytes.fromhex("0001 0000 0005 01 03 02 0000")  # register 0: 0
            s.sendall(bytes.fromhex("0002 0001 0006 01 03 0000 0001"))  # protocol id 1
            assert s.recv(64) == b""  # closed
    finally:
        p.terminate()
        _, err = p.communicate(timeout=10)
    assert err == ""
