"""Signals and the thread that waits, not the one that opened the line:
a client connected in another thread (a pool's, a worker's) and read from
the main thread is stopped by a signal handler that raises, as one opened
there is; one opened in the main thread and read in another never calls
into Python while it waits. Real peers: a pseudo-terminal and TCP."""

from __future__ import annotations

import signal
import socket
import sys
import threading
import time
from typing import Any

import pytest
from wire_peers import RawPty, RawTcp

import pymb


class _Interrupt(Exception):
    pass


def _client(transport: str, port: Any) -> pymb.Client:
    if transport == "rtu":
        return pymb.RtuClient(port, 115200, slave=1, timeout=3)
    return pymb.TcpClient("127.0.0.1", port, slave=1, timeout=3)


@pytest.mark.parametrize("transport", ["rtu", "tcp"])
def test_a_signal_stops_a_main_thread_wait_on_a_line_opened_elsewhere(transport: str) -> None:
    def handler(signum: int, frame: object) -> None:
        raise _Interrupt

    peer = RawPty(lambda i, f: []) if transport == "rtu" else RawTcp(lambda i, f: [])
    old = signal.signal(signal.SIGALRM, handler)
    try:
        with peer:
            c = _client(transport, peer.port)
            opener = threading.Thread(target=c.connect)
            opener.start()
            opener.join(10)
            assert c.connected
            signal.setitimer(signal.ITIMER_REAL, 0.2)
            t0 = time.monotonic()
            with pytest.raises(_Interrupt):
                c.read_holding_registers(0, 1)
            assert time.monotonic() - t0 < 1.0  # not the 3 s timeout
            c.close()
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


@pytest.mark.parametrize("transport", ["rtu", "tcp"])
def test_a_wait_in_another_thread_never_calls_into_python(transport: str) -> None:
    calls = [0]

    def profile(frame: Any, event: str, arg: object) -> None:
        if event == "call" and frame.f_code.co_name == "pymb_py_interrupted":
            calls[0] += 1

    def read(c: pymb.Client) -> None:
        sys.setprofile(profile)
        try:
            with pytest.raises(pymb.ModbusTimeout):
                c.read_holding_registers(0, 1)
        finally:
            sys.setprofile(None)

    peer = RawPty(lambda i, f: []) if transport == "rtu" else RawTcp(lambda i, f: [])
    with peer, _client(transport, peer.port) as c:  # opened here, in the main thread
        c.timeout = 0.4
        t = threading.Thread(target=read, args=(c,))
        t.start()
        t.join(30)
    assert calls == [0]


@pytest.mark.parametrize("transport", ["rtu", "tcp"])
def test_a_signal_handler_that_closes_the_client_ends_its_wait(transport: str) -> None:
    # The handler runs inside the read's own wait, in C, on this thread: the
    # line cannot be freed under it. The close is done as soon as the C call
    # has returned: the read fails at once, the client is closed, and it
    # connects again.
    peer = RawPty(lambda i, f: []) if transport == "rtu" else RawTcp(lambda i, f: [])
    with peer:
        c = _client(transport, peer.port)
        c.connect()
        old = signal.signal(signal.SIGALRM, lambda signum, frame: c.close())
        try:
            signal.setitimer(signal.ITIMER_REAL, 0.2)
            t0 = time.monotonic()
            with pytest.raises(pymb.ModbusConnectionError,
                               match="the client was closed while this request waited"):
                c.read_holding_registers(0, 1)
            assert time.monotonic() - t0 < 1.0  # not the 3 s timeout
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, old)
        assert not c.connected
        assert c.fileno() == -1
        with pytest.raises(pymb.ModbusConnectionError, match="not connected"):
            c.read_holding_registers(0, 1)
        c.connect()
        assert c.connected
        c.close()


def test_a_handler_that_closes_the_client_as_its_reply_comes_still_closes_it() -> None:
    # The handler closes the client in the read's wait just as the reply has
    # come (it sends it itself, from the device's end, first): the wait must
    # not go on to read that reply and return, leaving the line open under a
    # client that was closed (connected, reads answered).
    with socket.create_server(("127.0.0.1", 0)) as server:
        c = pymb.TcpClient("127.0.0.1", server.getsockname()[1], slave=1, timeout=3)
        c.connect()
        conn, _ = server.accept()
        conn.settimeout(30)
        main = threading.main_thread().ident
        assert main is not None

        def signal_once_sent() -> None:  # the request on the wire: the read waits in C
            conn.recv(260, socket.MSG_PEEK)
            signal.pthread_kill(main, signal.SIGALRM)

        with conn:
            def handler(signum: int, frame: object) -> None:
                adu = conn.recv(260)  # the read's request, on the device's side
                conn.sendall(adu[:4] + b"\x00\x05" + adu[6:8] + b"\x02\x00\x07")
                c.close()

            old = signal.signal(signal.SIGALRM, handler)
            sender = threading.Thread(target=signal_once_sent)
            try:
                sender.start()
                with pytest.raises(pymb.ModbusConnectionError,
                                   match="the client was closed while this request waited"):
                    c.read_holding_registers(0, 1)
            finally:
                sender.join(30)
                signal.signal(signal.SIGALRM, old)
            assert not c.connected
            with pytest.raises(pymb.ModbusConnectionError, match="not connected"):
                c.read_holding_registers(0, 1)
