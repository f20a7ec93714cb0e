"""``pymb serve`` in front of a scripted RTU peer on a real pseudo-terminal,
used by independent clients: pymodbus, mbpoll (libmodbus's client) and a raw
socket written from the specification that also sends hostile frames."""

from __future__ import annotations

import shutil
import socket
import struct
import subprocess
import threading
import time
from collections.abc import Iterator

import pytest
from conftest import rss_kb, wait_until
from peers import PtyPeer
from servekit import RawClient, Served, mbap, read_pdu, serve_args, words


@pytest.fixture
def peer() -> Iterator[PtyPeer]:
    with PtyPeer() as p:
        yield p


def test_pymodbus_reads_and_writes_through_one_line(peer: PtyPeer) -> None:
    from pymodbus.client import ModbusTcpClient
    with Served(*serve_args(peer.port)) as s:
        c = ModbusTcpClient("127.0.0.1", port=s.port, timeout=5)
        assert c.connect()  # type: ignore[no-untyped-call]
        try:
            r = c.read_holding_registers(10, count=5, device_id=3)
            assert r.registers == [(i * 7) & 0xFFFF for i in range(10, 15)]
            assert not c.write_register(100, 0xBEEF, device_id=3).isError()
            assert peer.memory.holding[100] == 0xBEEF
            assert not c.write_registers(200, [1, 2, 3], device_id=3).isError()
            assert c.read_holding_registers(200, count=3, device_id=3).registers == [1, 2, 3]
            assert c.read_coils(0, count=10, device_id=3).bits[:10] == \
                [bool(i % 3 == 0) for i in range(10)]
            assert not c.write_coil(5, True, device_id=3).isError()
            assert peer.memory.coils[5] == 1
            r = c.readwrite_registers(read_address=300, read_count=2, write_address=300,
                                      values=[7, 8], device_id=3)
            assert r.registers == [7, 8]
            # the device's own exception comes back as it was
            r = c.read_holding_registers(60001, count=2, device_id=3)
            assert r.isError()
            assert r.exception_code == 2
        finally:
            c.close()  # type: ignore[no-untyped-call]
        assert s.stop() == 0
    assert all(slave == 3 for slave, _ in peer.requests)


@pytest.mark.skipif(shutil.which("mbpoll") is None, reason="mbpoll is not installed")
def test_mbpoll_reads_through_serve(peer: PtyPeer) -> None:
    with Served(*serve_args(peer.port)) as s:
        r = subprocess.run(["mbpoll", "-m", "tcp", "-p", str(s.port), "-a", "9", "-t", "4",
                            "-0", "-r", "20", "-c", "4", "-1", "127.0.0.1"],
                           capture_output=True, text=True, timeout=30)
    assert r.returncode == 0, r.stdout + r.stderr
    for i in range(20, 24):
        assert f"[{i}]: \t{(i * 7) & 0xFFFF}" in r.stdout


def test_malformed_requests_are_answered_without_touching_the_line(peer: PtyPeer) -> None:
    with Served(*serve_args(peer.port)) as s:
        c = RawClient(s.port)
        assert c.ask(1, 3, read_pdu(0, 0)) == bytes((0x83, 3))         # quantity 0
        assert c.ask(2, 3, read_pdu(0, 126)) == bytes((0x83, 3))       # 126 registers
        assert c.ask(3, 3, read_pdu(65535, 2)) == bytes((0x83, 2))     # past 65535
        assert c.ask(4, 3, bytes((0x10, 0, 0, 0, 2, 3, 0, 1, 0))) == bytes((0x90, 3))
        assert c.ask(5, 3, bytes((0x85, 0, 0))) == bytes((0x85, 1))    # not a function
        assert c.ask(6, 0, read_pdu(0, 1)) == bytes((0x83, 0x0A))      # broadcast unit
        assert peer.requests == []
        # the connection is still good
        assert words(c.ask(7, 3, read_pdu(1, 1))) == [7]
        c.close()


def test_pipelined_and_split_requests_keep_their_transaction_ids(peer: PtyPeer) -> None:
    with Served(*serve_args(peer.port)) as s:
        c = RawClient(s.port)
        frames = b"".join(mbap(1000 + i, 4, read_pdu(i, 1)) for i in range(10))
        c.send(frames)  # ten requests in one segment
        got = {}
        for _ in range(10):
            tid, unit, pdu = c.reply()
            assert unit == 4
            got[tid] = words(pdu)
        assert got == {1000 + i: [(i * 7) & 0xFFFF] for i in range(10)}
        one = mbap(0xFFFF, 4, read_pdu(50, 2))
        for b in one:  # a byte at a time
            c.send(bytes((b,)))
            time.sleep(0.002)
        tid, _, pdu = c.reply()
        assert tid == 0xFFFF
        assert words(pdu) == [350, 357]
        c.close()


@pytest.mark.parametrize("garbage", [
    b"GET / HTTP/1.1\r\nHost: x\r\n\r\n",            # not Modbus at all
    struct.pack(">HHHB", 1, 1, 6, 1) + read_pdu(0, 1),  # protocol id 1
    struct.pack(">HHHB", 1, 0, 1, 1),                  # length 1: no function code
    struct.pack(">HHHB", 1, 0, 300, 1) + bytes(300),   # longer than any PDU
])
def test_a_clients_garbage_closes_that_client_only(peer: PtyPeer, garbage: bytes) -> None:
    with Served(*serve_args(peer.port)) as s:
        good = RawClient(s.port)
        bad = RawClient(s.port)
        assert words(good.ask(1, 2, read_pdu(3, 1))) == [21]
        bad.send(garbage)
        assert bad.closed_by_server()
        assert words(good.ask(2, 2, read_pdu(4, 1))) == [28]
        good.close()
        bad.close()
        wait_until(lambda: any("not Modbus TCP" in line for line in s.stderr_lines),
                   "the event line about the garbage")


def test_a_silent_device_is_answered_0x0B_and_the_line_goes_on(peer: PtyPeer) -> None:
    peer.hook = lambda slave, pdu, normal: [] if slave == 66 else None
    with Served(*serve_args(peer.port)) as s:
        c = RawClient(s.port)
        assert c.ask(1, 66, read_pdu(0, 1)) == bytes((0x83, 0x0B))
        assert words(c.ask(2, 65, read_pdu(0, 1))) == [0]
        c.close()


def test_units_are_routed(peer: PtyPeer) -> None:
    with Served(*serve_args(peer.port, ["--unit", "5=17", "--unit", "6=5"])) as s:
        c = RawClient(s.port)
        assert c.ask(1, 5, bytes((6, 0, 9, 0, 42))) == bytes((6, 0, 9, 0, 42))
        assert c.ask(2, 6, read_pdu(9, 1))
        assert c.ask(3, 7, read_pdu(9, 1))
        c.close()
    assert [slave for slave, _ in peer.requests] == [17, 5, 7]


def test_32_clients_read_and_write_at_once_with_no_cross_talk(peer: PtyPeer) -> None:
    rounds = 25
    errors: list[str] = []

    def client(n: int, port: int) -> None:
        try:
            c = RawClient(port, timeout=30)
            base = 1000 + 10 * n
            for r in range(rounds):
                value = (n << 8) | r
                tid = (n * rounds + r) & 0xFFFF
                assert c.ask(tid, 1 + n % 3, struct.pack(">BHH", 6, base, value)) == \
                    struct.pack(">BHH", 6, base, value)
                got = words(c.ask(tid ^ 0x8000, 1 + n % 3, read_pdu(base, 1)))
                if got != [value]:
                    errors.append(f"client {n} round {r}: wrote {value:#x}, read {got}")
            c.close()
        except Exception as e:  # every client's failure is reported
            errors.append(f"client {n}: {e!r}")

    with Served(*serve_args(peer.port)) as s:
        threads = [threading.Thread(target=client, args=(n, s.port)) for n in range(32)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(120)
        assert s.stop() == 0
    assert errors == []
    assert len(peer.requests) == 32 * rounds * 2  # nothing lost, nothing twice


def test_clients_that_drop_or_never_read_cost_the_others_nothing(peer: PtyPeer) -> None:
    # The scripted device shares this process with the hog's loop: at a
    # loaded machine's worst it answers in more than serve_args' 0.5 s. What
    # is tested is that the good client is answered at all, not how fast.
    with Served(*serve_args(peer.port, ["--max-clients", "2000", "--timeout", "3"])) as s:
        good = RawClient(s.port)
        assert words(good.ask(1, 1, read_pdu(2, 1))) == [14]
        rss0 = rss_kb(s.proc.pid)
        # 1,000 connections opened and dropped, half of them mid-transaction
        for i in range(1000):
            sock = socket.create_connection(("127.0.0.1", s.port))
            if i % 2:
                sock.sendall(mbap(i, 1, read_pdu(i, 1)))
            sock.close()
        # a client that sends many requests and never reads its replies
        hog = socket.create_connection(("127.0.0.1", s.port))
        hog.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        hog.setblocking(False)
        burst = mbap(1, 1, read_pdu(0, 125)) * 200
        sent = 0
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and sent < 200 * len(burst):
            try:
                sent += hog.send(burst)
            except BlockingIOError:
                time.sleep(0.05)
        for i in range(20):
            assert words(good.ask(100 + i, 1, read_pdu(i, 1))) == [(i * 7) & 0xFFFF]
        grew = rss_kb(s.proc.pid) - rss0
        assert grew < 20_000, f"pymb serve grew by {grew} kB"
        hog.close()
        good.close()
        wait_until(lambda: s.proc.poll() is None, "pymb serve still running")
        assert s.stop() == 0


@pytest.mark.parametrize(("extra", "code", "said"), [
    (["--unit", "5"], 2, "--unit needs LISTEN=UPSTREAM"),
    (["--unit", "0=3"], 2, "the listen unit must be 1..255"),
    (["--max-clients", "0"], 2, "--max-clients must be at least 1"),
    (["--tls", "--cert", "c.pem"], 2, "--tls needs --key FILE"),
    (["--write-roles", "operator"], 2, "--write-roles needs --tls"),
    # a certificate without --tls: refused, never served as plaintext
    (["--cert", "c.pem", "--key", "c.key", "--ca", "ca.pem"], 2,
     "--cert/--key/--ca are for the TLS server: give --tls too"),
    (["--ca", "ca.pem"], 2, "--ca is for the TLS server: give --tls too"),
    (["--max-inflight", "4"], 2, "--max-inflight needs --tcp HOST:PORT, a plain Modbus TCP"),
])
def test_a_users_mistake_is_one_line(peer: PtyPeer, extra: list[str], code: int,
                                     said: str) -> None:
    from conftest import run_pymb
    r = run_pymb("serve", *serve_args(peer.port, extra), "--listen", "127.0.0.1:0", timeout=30)
    assert r.returncode == code, r.stderr
    assert said in r.stderr
    assert "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def test_a_port_in_use_exits_4(peer: PtyPeer) -> None:
    from conftest import run_pymb
    with socket.create_server(("127.0.0.1", 0)) as taken:
        port = taken.getsockname()[1]
        r = run_pymb("serve", *serve_args(peer.port), "--listen", f"127.0.0.1:{port}",
                     timeout=30)
    assert r.returncode == 4, r.stderr
    assert "cannot listen on 127.0.0.1:" in r.stderr
    assert "Traceback" not in r.stderr


def test_the_reads_of_a_client_that_has_gone_are_not_sent(peer: PtyPeer) -> None:
    peer.hook = lambda slave, pdu, normal: [] if slave == 9 else None  # unit 9 is silent
    with Served(*serve_args(peer.port)) as s:
        c = RawClient(s.port)
        # 8 reads and a write to a silent device (0.5 s each), then gone
        c.send(b"".join(mbap(i, 9, read_pdu(i, 1)) for i in range(8)) +
               mbap(8, 9, bytes((6, 0, 3, 0, 7))))
        wait_until(lambda: len(peer.requests) >= 1, "the first request on the line")
        c.close()
        # Another client's read waits behind what the gone one left.
        other = RawClient(s.port)
        assert words(other.ask(20, 1, read_pdu(2, 1))) == [14]
        other.close()
        sent = [pdu for slave, pdu in peer.requests if slave == 9]
        reads = [pdu for pdu in sent if pdu[0] == 3]
        assert len(reads) <= 2, sent  # the one under way (and one taken before the close)
        assert sent[-1] == bytes((6, 0, 3, 0, 7))  # a write is sent all the same
        assert s.stop() == 0
    summary = s.stderr_lines[-1]
    assert f"{8 - len(reads)} not sent (their clients had gone)" in summary, summary


def test_the_writes_of_a_gone_client_still_in_its_buffer_are_sent(peer: PtyPeer) -> None:
    # docs/serve.md: a client that disconnects has its writes sent all the
    # same, as it gave them, also those behind its first 16 requests (still in
    # its buffer when its connection was lost); its reads there are not sent,
    # and the summary counts them with the others.
    peer.hook = lambda slave, pdu, normal: [] if slave == 9 else None  # unit 9 is silent
    write = bytes((6, 0, 3, 0, 7))
    with Served(*serve_args(peer.port)) as s:
        c = RawClient(s.port)
        c.send(b"".join(mbap(i, 9, read_pdu(i, 1)) for i in range(20)) + mbap(20, 9, write))
        wait_until(lambda: len(peer.requests) >= 1, "the first request on the line")
        c.close()
        wait_until(lambda: (9, write) in peer.requests, "the gone client's write on the line")
        sent = [pdu for slave, pdu in peer.requests if slave == 9]
        assert s.stop() == 0
    reads = [pdu for pdu in sent if pdu[0] == 3]
    assert sent[-1] == write
    summary = s.stderr_lines[-1]
    assert f"{20 - len(reads)} not sent (their clients had gone)" in summary, summary


def test_a_burst_of_requests_waits_its_turn_16_at_a_time(peer: PtyPeer) -> None:
    # docs/serve.md: each client has at most 16 requests waiting. A client
    # that sends 100 reads in one write has 16 of them queued for the line,
    # the rest wait in its own buffer: another client's read is sent after
    # at most those 16 (and the one under way), and the burst is answered
    # whole, in order.
    peer.hook = lambda slave, pdu, normal: (
        [(0.02, peer.frame(slave, normal))] if slave == 9 and normal else None)
    with Served(*serve_args(peer.port)) as s:
        burst = RawClient(s.port, timeout=60)
        burst.send(b"".join(mbap(i, 9, read_pdu(i, 1)) for i in range(100)))
        wait_until(lambda: len(peer.requests) >= 2, "the burst's first requests on the line")
        other = RawClient(s.port)
        before = len(peer.requests)
        assert words(other.ask(1, 1, read_pdu(2, 1))) == [14]
        ahead = [slave for slave, _ in peer.requests].index(1) - before
        assert ahead <= 18, f"{ahead} more of the burst's requests were sent first"
        for i in range(100):
            tid, unit, pdu = burst.reply()
            assert (tid, unit, words(pdu)) == (i, 9, [(i * 7) & 0xFFFF])
        burst.close()
        other.close()
        assert s.stop() == 0


def test_a_client_that_half_closes_is_taken_as_gone(peer: PtyPeer) -> None:
    # docs/serve.md: a client that shuts its sending side (a close looks the
    # same to the server until a reply meets its RST) is taken as gone: its
    # connection is closed, its reads waiting behind the one under way
    # (a silent unit: 0.5 s each) are not sent.
    peer.hook = lambda slave, pdu, normal: [] if slave == 9 else None
    with Served(*serve_args(peer.port)) as s:
        c = RawClient(s.port)
        c.send(b"".join(mbap(i, 9, read_pdu(i, 1)) for i in range(8)))
        wait_until(lambda: len(peer.requests) >= 1, "the first request on the line")
        c.sock.shutdown(socket.SHUT_WR)
        assert c.closed_by_server()
        c.close()
        other = RawClient(s.port)  # its read waits behind what the gone one left
        assert words(other.ask(20, 1, read_pdu(2, 1))) == [14]
        other.close()
        assert s.stop() == 0
    reads = [pdu for slave, pdu in peer.requests if slave == 9]
    assert len(reads) <= 2, reads  # the one under way (and one taken before the close)
    summary = s.stderr_lines[-1]
    assert f"{8 - len(reads)} not sent (their clients had gone)" in summary, summary


def test_a_stop_drops_the_queued_requests_of_a_silent_device(peer: PtyPeer) -> None:
    peer.hook = lambda slave, pdu, normal: []  # nobody answers: each request takes --timeout
    with Served(*serve_args(peer.port)) as s:
        c = RawClient(s.port)
        c.send(b"".join(mbap(i, 9, read_pdu(i, 1)) for i in range(16)))  # 8 s of timeouts
        wait_until(lambda: len(peer.requests) >= 1, "the first request on the line")
        t = time.monotonic()
        assert s.stop() == 0
        assert time.monotonic() - t < 4.0  # the one under way, not all sixteen
        c.close()


def test_past_max_clients_a_connection_is_refused_and_the_others_go_on(peer: PtyPeer) -> None:
    # docs/serve.md: at most --max-clients are connected at once; more are refused.
    with Served(*serve_args(peer.port, ["--max-clients", "2"])) as s:
        a, b = RawClient(s.port), RawClient(s.port)
        assert words(a.ask(1, 1, read_pdu(0, 1))) == [0]
        assert words(b.ask(1, 1, read_pdu(0, 1))) == [0]
        third = RawClient(s.port)
        assert third.closed_by_server()
        third.close()
        wait_until(lambda: any("refused, 2 clients are connected" in line
                               for line in s.stderr_lines), "the refusal's event line")
        assert words(a.ask(2, 1, read_pdu(0, 1))) == [0]
        b.close()  # a place frees up: the next client is served
        for _ in range(50):
            c = RawClient(s.port)
            try:
                assert words(c.ask(3, 1, read_pdu(0, 1))) == [0]
                break
            except ConnectionError:
                c.close()
                time.sleep(0.1)  # the server has not seen b go yet
        else:
            raise AssertionError("no client was served after one left")
        c.close()
        a.close()
        assert s.stop() == 0


def test_an_ipv6_listen_address_is_printed_in_brackets(peer: PtyPeer) -> None:
    # The first line's address is one a client takes back (mbaps://[::1]:PORT).
    with Served(*serve_args(peer.port), listen="[::1]:0") as s:
        assert s.first_line.startswith(f"pymb serve: mbap://[::1]:{s.port} -> "), s.first_line
        with socket.create_connection(("::1", s.port), timeout=10) as raw:
            raw.sendall(mbap(1, 1, read_pdu(0, 1)))
            assert raw.recv(100)[7:] == bytes((3, 2, 0, 0))
        assert s.stop() == 0
