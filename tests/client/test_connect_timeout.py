"""A TCP connect that gets no answer (a host that is down, a firewall that
drops it: here a listener whose backlog is full, so the kernel drops the
connection request) fails after the client's own timeout, as a timed-out
connect, over TCP, Modbus/TCP Security and RTU over TCP, blocking and
asyncio alike."""

from __future__ import annotations

import asyncio
import contextlib
import errno
import socket
import time
from collections.abc import Iterator

import pytest

import pymb
import pymb.aio


@pytest.fixture
def full_listener() -> Iterator[int]:
    """A port on 127.0.0.1 that never answers a new connection request: its
    listener takes no more (backlog 0) and never accepts."""
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(0)
    port: int = srv.getsockname()[1]
    held = []
    for _ in range(3):  # fill the accept queue; later requests are dropped
        s = socket.socket()
        s.setblocking(False)
        with contextlib.suppress(BlockingIOError):
            s.connect(("127.0.0.1", port))
        held.append(s)
    time.sleep(0.1)
    try:
        yield port
    finally:
        for s in held:
            s.close()
        srv.close()


def timed_connect(client: pymb.Client) -> tuple[pymb.ModbusConnectionError, float]:
    t0 = time.monotonic()
    with pytest.raises(pymb.ModbusConnectionError) as ei:
        client.connect()
    return ei.value, time.monotonic() - t0


@pytest.mark.parametrize("timeout", [0.2, 1.5])
@pytest.mark.parametrize("kind", ["tcp", "rtu-over-tcp"])
def test_a_connect_nobody_answers_takes_the_clients_timeout(
        full_listener: int, kind: str, timeout: float) -> None:
    cls = pymb.TcpClient if kind == "tcp" else pymb.RtuOverTcpClient
    client = cls("127.0.0.1", full_listener, slave=1, timeout=timeout)
    e, took = timed_connect(client)
    # The lower bound tells the client's timeout from libmodbus's 0.5 s (at
    # 1.5 s); the upper one only that it ends (a loaded machine is slow).
    assert timeout - 0.05 <= took < timeout + 3, took
    assert e.errno == errno.ETIMEDOUT
    assert "no answer to the connection request within the timeout" in str(e), str(e)
    assert not client.connected


def test_the_same_over_tls_and_asyncio(full_listener: int) -> None:
    tls = pymb.TcpClient("127.0.0.1", full_listener, slave=1, timeout=1.2,
                         tls=pymb.TlsConfig(check_hostname=False))
    e, took = timed_connect(tls)
    assert 1.15 <= took < 4.2, took
    assert e.errno == errno.ETIMEDOUT

    async def main() -> float:
        c = pymb.aio.AsyncTcpClient("127.0.0.1", full_listener, slave=1, timeout=1.2)
        t0 = time.monotonic()
        with pytest.raises(pymb.ModbusConnectionError, match="within the timeout"):
            await c.connect()
        await c.close()
        return time.monotonic() - t0

    took = asyncio.run(main())
    assert 1.15 <= took < 4.2, took
