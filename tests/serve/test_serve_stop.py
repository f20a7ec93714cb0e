"""``pymb serve`` stops promptly on SIGTERM/SIGINT while a client's request
waits on an upstream that never answers: the request is abandoned with the
process, whatever the reply timeout."""

from __future__ import annotations

import signal
import socket
import time
from collections.abc import Iterator

import pytest
from servekit import RawClient, Served, mbap

READ = bytes((0x03, 0, 0, 0, 1))  # read one holding register


@pytest.fixture
def silent() -> Iterator[socket.socket]:
    """A TCP listener that accepts and never answers."""
    with socket.create_server(("127.0.0.1", 0)) as listener:
        listener.settimeout(20)
        yield listener


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
@pytest.mark.parametrize("flag", ["--rtu-over-tcp", "--tcp"])
def test_a_signal_ends_serve_promptly_with_a_request_in_flight(
        silent: socket.socket, flag: str, sig: signal.Signals) -> None:
    upstream = f"127.0.0.1:{silent.getsockname()[1]}"
    with Served(flag, upstream, "--timeout", "30", "--quiet") as s:
        client = RawClient(s.port)
        try:
            client.sock.sendall(mbap(1, 1, READ))
            conn, _ = silent.accept()
            with conn:
                conn.settimeout(20)
                assert conn.recv(256)  # the request is on the upstream: in flight
                t0 = time.monotonic()
                s.proc.send_signal(sig)
                code = s.proc.wait(20)
                took = time.monotonic() - t0
        finally:
            client.sock.close()
    assert code == 0, s.stderr_lines
    assert took < 3, f"pymb serve took {took:.1f} s to stop"
    # the summary counts the request it never answered, in words that fit one
    assert s.stderr_lines[-1].startswith("pymb serve: 1 request from 1 connection; "), \
        s.stderr_lines
    assert s.stderr_lines[-1].endswith(" while unreachable, 1 dropped at the stop"), \
        s.stderr_lines
