"""close() of an async client while other tasks wait on it, and the loop's
end (Ctrl-C in asyncio.run) with a request on the wire: the request on the
line ends at once with ModbusConnectionError, those queued before the close
never go out, settings queued before it still apply; nothing waits for the
request's own timeout. Real peers that stay silent: a pseudo-terminal, TCP
and UDP on 127.0.0.1."""

from __future__ import annotations

import asyncio
import errno
import os
import signal
import socket
import subprocess
import sys
import textwrap
import time
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager

import pytest
from aiokit import pymb_threads, until
from wire_peers import RawPty, RawTcp

import pymb
import pymb.aio

TIMEOUT = 5.0  #: the requests' own timeout: nothing may wait for it
PROMPT = 1.5  #: what "at once" may take on a loaded machine (50 ms unloaded)


@asynccontextmanager
async def silent_client(kind: str) -> AsyncIterator[tuple[pymb.aio.AsyncClient,
                                                           Callable[[], int]]]:
    """A connected async client of ``kind`` whose peer never answers, and
    how many requests the peer has seen."""
    c: pymb.aio.AsyncClient
    if kind in ("rtu", "ascii"):
        with RawPty(lambda i, f: []) as pty:
            cls = pymb.aio.AsyncRtuClient if kind == "rtu" else pymb.aio.AsyncAsciiClient
            c = cls(pty.port, 115200, slave=1, timeout=TIMEOUT)
            async with c:
                yield c, lambda: len(pty.requests)
    elif kind == "udp":
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.bind(("127.0.0.1", 0))
            s.setblocking(False)
            seen: list[bytes] = []

            def heard() -> int:
                while True:
                    try:
                        seen.append(s.recv(600))
                    except BlockingIOError:
                        return len(seen)

            c = pymb.aio.AsyncUdpClient("127.0.0.1", s.getsockname()[1], slave=1,
                                        timeout=TIMEOUT, retries=0)
            async with c:
                yield c, heard
    else:
        framing = kind == "rtu-over-tcp"
        with RawTcp(lambda i, f: [], rtu_frames=framing) as tcp:
            c = (pymb.aio.AsyncRtuOverTcpClient("127.0.0.1", tcp.port, slave=1, timeout=TIMEOUT)
                 if framing else
                 pymb.aio.AsyncTcpClient("127.0.0.1", tcp.port, slave=1, timeout=TIMEOUT))
            async with c:
                yield c, lambda: len(tcp.requests)


@pytest.mark.parametrize("kind", ["rtu", "ascii", "tcp", "rtu-over-tcp", "udp"])
def test_close_ends_the_request_on_the_wire_and_drops_those_queued(kind: str) -> None:
    async def main() -> None:
        async with silent_client(kind) as (c, heard):
            on_wire = asyncio.ensure_future(c.read_holding_registers(1, 1))
            await until(lambda: heard() == 1, "the first request on the wire")
            queued = [asyncio.ensure_future(c.read_holding_registers(a, 1)) for a in (2, 3)]
            setting = asyncio.ensure_future(c.set_timeout(0.75))
            await asyncio.sleep(0.1)
            t0 = time.monotonic()
            await c.close()
            assert time.monotonic() - t0 < PROMPT  # not the request's 5 s timeout
            got = await asyncio.gather(on_wire, *queued, setting, return_exceptions=True)
            first, *rest, timeout_set = got
            assert isinstance(first, pymb.ModbusConnectionError), repr(first)
            assert "the client was closed while this request waited" in str(first)
            assert first.errno == errno.ECANCELED
            for e in rest:
                assert isinstance(e, pymb.ModbusConnectionError), repr(e)
                assert "closed before this request's turn" in str(e)
                assert e.errno == errno.ECANCELED
            assert timeout_set is None  # a setting is kept
            assert c.timeout == 0.75
            assert heard() == 1  # the queued requests never went out
            assert not c.connected
            assert pymb_threads() == []
            with pytest.raises(pymb.ModbusConnectionError, match="not connected"):
                await c.read_holding_registers(1, 1)
            await c.connect()  # and it opens again
            assert c.connected

    asyncio.run(main())


def test_the_loops_end_does_not_wait_for_the_request_on_the_wire() -> None:
    pending: list[asyncio.Future[object]] = []

    async def main(port: int) -> None:
        c = pymb.aio.AsyncTcpClient("127.0.0.1", port, slave=1, timeout=TIMEOUT)
        await c.connect()
        pending.append(asyncio.ensure_future(c.read_holding_registers(0, 1)))
        await until(lambda: peer.requests, "the request on the wire")

    with RawTcp(lambda i, f: []) as peer:
        t0 = time.monotonic()
        asyncio.run(main(peer.port))
        assert time.monotonic() - t0 < PROMPT + 1
        assert pymb_threads() == []


CTRL_C = textwrap.dedent("""
    import asyncio, socket, sys, time
    import pymb.aio

    srv = socket.create_server(("127.0.0.1", 0))  # accepts (the kernel's), never answers

    async def main() -> None:
        async with pymb.aio.AsyncTcpClient("127.0.0.1", srv.getsockname()[1], slave=1,
                                           timeout=30) as c:
            print("waiting", flush=True)
            await c.read_holding_registers(0, 1)

    t0 = time.monotonic()
    try:
        asyncio.run(main())
    except KeyboardInterrupt:
        print(f"interrupted {time.monotonic() - t0:.2f}", flush=True)
""")


def test_ctrl_c_in_asyncio_run_ends_a_request_at_once() -> None:
    proc = subprocess.Popen([sys.executable, "-c", CTRL_C], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline() == "waiting\n"
        time.sleep(0.3)
        sent = time.monotonic()
        os.kill(proc.pid, signal.SIGINT)
        out, err = proc.communicate(timeout=20)
        took = time.monotonic() - sent
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    assert out.startswith("interrupted "), (out, err)
    assert took < PROMPT + 1, took  # not the request's 30 s
    assert proc.returncode == 0, err
    assert "Traceback" not in err, err
    assert "Task was destroyed" not in err, err
