"""``AsyncTcpClient.next_tid`` is read at once, as every forwarded attribute
is: a request in flight on the worker does not hold the event loop (the id
is None meanwhile, and known again once the request has ended)."""

from __future__ import annotations

import asyncio
import socket
import struct
import threading

import pymb.aio


def _server(listener: socket.socket, got: threading.Event, answer: threading.Event) -> None:
    """One connection: its first request is answered once ``answer`` is set
    (two registers, 7 and 8)."""
    conn, _ = listener.accept()
    with conn:
        conn.settimeout(30)
        request = conn.recv(260)
        got.set()
        answer.wait(30)
        tid = request[:2]
        conn.sendall(tid + struct.pack(">HHBBB", 0, 7, request[6], 3, 4) + struct.pack(">HH", 7, 8))
        conn.recv(260)  # until the client closes


def test_next_tid_does_not_wait_for_the_request_in_flight() -> None:
    listener = socket.create_server(("127.0.0.1", 0))
    got, answer = threading.Event(), threading.Event()
    server = threading.Thread(target=_server, args=(listener, got, answer), daemon=True)
    server.start()

    async def main() -> tuple[int | None, list[int], int | None]:
        client = pymb.aio.AsyncTcpClient("127.0.0.1", listener.getsockname()[1], slave=1,
                                         timeout=5.0)
        await client.connect()
        try:
            read = asyncio.ensure_future(client.read_holding_registers(0, 2))
            while not got.is_set():
                await asyncio.sleep(0.01)
            # the reply comes only after this read: a loop held until the
            # request ends would see it time out instead
            tid = client.next_tid
            answer.set()
            regs = list(await read)
            return tid, regs, client.next_tid
        finally:
            answer.set()
            await client.close()

    try:
        in_flight, regs, after = asyncio.run(main())
    finally:
        listener.close()
        server.join(30)
    assert regs == [7, 8]
    assert in_flight is None
    assert after == 2  # the read was transaction 1
