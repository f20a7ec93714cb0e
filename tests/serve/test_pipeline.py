"""``pymb serve --tcp``: many clients' requests in flight to a Modbus TCP
upstream at once, bounded by ``--max-inflight``, against a scripted device
that answers out of order (and one unit never), and against pymodbus's TCP
server: every reply reaches the client that asked, with its own transaction
id, and carries the registers of its own request."""

from __future__ import annotations

import contextlib
import select
import socket
import struct
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from types import TracebackType
from typing import Self

import pytest
from conftest import wait_until
from servekit import RawClient, Served, mbap, read_pdu, words
from wire_peers import build_libmodbus_server, libmodbus_server, pymodbus_server

SILENT_UNIT = 99  #: the scripted device never answers this unit
LATE_UNIT = 98  #: ... and answers this one LATE seconds after it came
LATE = 1.5


def _value(unit: int, address: int) -> int:
    return (unit * 1000 + address) & 0xFFFF


class OutOfOrder:
    """A Modbus TCP device on 127.0.0.1 that holds requests until ``batch``
    are waiting (or none came for 20 ms) and then answers them last first:
    read holding registers (03) only, each register ``unit * 1000 +
    address``. Counts the most requests it held unanswered at once."""

    def __init__(self, batch: int = 4) -> None:
        self.batch = batch
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port = self.listener.getsockname()[1]
        self.most_waiting = 0
        self.requests = 0
        self.connections = 0
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        self.listener.settimeout(0.2)
        while not self._stop.is_set():
            try:
                conn, _ = self.listener.accept()
            except TimeoutError:
                continue
            self.connections += 1
            with conn:
                self._serve(conn)

    def _serve(self, conn: socket.socket) -> None:
        buf = b""
        waiting: list[tuple[int, int, bytes]] = []
        while not self._stop.is_set():
            ready, _, _ = select.select([conn], [], [], 0.02)
            if ready:
                data = conn.recv(4096)
                if not data:
                    return
                buf += data
                while len(buf) >= 6 and len(buf) >= 6 + struct.unpack(">H", buf[4:6])[0]:
                    n = 6 + struct.unpack(">H", buf[4:6])[0]
                    tid, _proto, _len, unit = struct.unpack(">HHHB", buf[:7])
                    pdu, buf = buf[7:n], buf[n:]
                    self.requests += 1
                    if unit == LATE_UNIT:
                        late = threading.Timer(LATE, self._send, (conn, [(tid, unit, pdu)]))
                        late.daemon = True
                        late.start()
                    elif unit != SILENT_UNIT:
                        waiting.append((tid, unit, pdu))
                        self.most_waiting = max(self.most_waiting, len(waiting))
            if waiting and (len(waiting) >= self.batch or not ready):
                self._send(conn, waiting[::-1])
                waiting.clear()

    def _send(self, conn: socket.socket, answers: list[tuple[int, int, bytes]]) -> None:
        out = b""
        for tid, unit, pdu in answers:
            fc, address, count = struct.unpack(">BHH", pdu)
            assert fc == 3
            regs = [_value(unit, address + i) for i in range(count)]
            reply = struct.pack(f">BB{count}H", 3, 2 * count, *regs)
            out += struct.pack(">HHHB", tid, 0, len(reply) + 1, unit) + reply
        with self._lock, contextlib.suppress(OSError):  # a late one after the close
            conn.sendall(out)

    def __enter__(self) -> Self:
        return self

    def __exit__(self, et: type[BaseException] | None, ev: BaseException | None,
                 tb: TracebackType | None) -> None:
        self._stop.set()
        self._thread.join(5)
        self.listener.close()


@pytest.fixture
def device() -> Iterator[OutOfOrder]:
    with OutOfOrder() as d:
        yield d


def _many_clients(port: int, *, clients: int, each: int, window: int, unit: int | None = None,
                  expect: dict[int, list[int]] | None = None) -> list[str]:
    """``clients`` threads, each with ``window`` requests outstanding at once
    on its own connection, ``each`` in all; every reply checked against its
    request (by transaction id). Returns the failures."""
    failures: list[str] = []

    def one(k: int) -> None:
        u = unit or 1 + k % 20
        c = RawClient(port, timeout=30)
        try:
            asked: dict[int, int] = {}
            sent = got = 0
            while got < each:
                while sent < each and len(asked) < window:
                    tid = (k * 1000 + sent) & 0xFFFF
                    address = (k * 37 + sent * 3) % 900
                    asked[tid] = address
                    c.send(mbap(tid, u, read_pdu(address, 3)))
                    sent += 1
                tid, runit, pdu = c.reply()
                got += 1
                if tid not in asked or runit != u:
                    failures.append(f"client {k}: a reply for tid {tid} unit {runit}")
                    return
                address = asked.pop(tid)
                want = ([_value(u, address + i) for i in range(3)] if expect is None
                        else expect[address])
                if words(pdu) != want:
                    failures.append(f"client {k}: tid {tid} got {words(pdu)}, not {want}")
        except Exception as e:  # said as a failure of this client
            failures.append(f"client {k}: {e!r}")
        finally:
            c.close()

    threads = [threading.Thread(target=one, args=(k,)) for k in range(clients)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    assert not any(t.is_alive() for t in threads)
    return failures


def test_many_clients_out_of_order_replies_each_to_its_asker(device: OutOfOrder) -> None:
    with Served("--tcp", f"127.0.0.1:{device.port}", "--max-inflight", "4",
                "--timeout", "10") as s:
        failures = _many_clients(s.port, clients=24, each=40, window=3)
        assert failures == []
        assert s.stop() == 0
    assert device.requests == 24 * 40
    # several in flight at once, never more than --max-inflight
    assert 2 <= device.most_waiting <= 4
    assert device.connections == 1


def test_max_inflight_1_sends_one_at_a_time(device: OutOfOrder) -> None:
    with Served("--tcp", f"127.0.0.1:{device.port}", "--max-inflight", "1",
                "--timeout", "10") as s:
        assert _many_clients(s.port, clients=6, each=10, window=3) == []
        assert s.stop() == 0
    assert device.most_waiting == 1


def test_a_silent_unit_is_answered_0x0b_and_the_others_are_served(device: OutOfOrder) -> None:
    with Served("--tcp", f"127.0.0.1:{device.port}", "--max-inflight", "2",
                "--timeout", "0.5") as s:
        silent = RawClient(s.port)
        try:
            for tid in range(4):  # both in-flight slots would be held by it
                silent.send(mbap(tid, SILENT_UNIT, read_pdu(0, 1)))
            assert _many_clients(s.port, clients=4, each=10, window=2) == []
            answers = sorted(silent.reply() for _ in range(4))
            assert answers == [(tid, SILENT_UNIT, bytes((0x83, 0x0B))) for tid in range(4)]
        finally:
            silent.close()
        assert s.stop() == 0
    # a unit that answers nothing is not one that drops requests sent together
    assert not any("one transaction at a time" in line for line in s.stderr_lines)


def test_an_upstream_that_is_not_there_is_answered_0x0a() -> None:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]  # bound, not listening: connections are refused
        with Served("--tcp", f"127.0.0.1:{port}", "--timeout", "2") as s:
            c = RawClient(s.port)
            try:
                assert c.ask(5, 1, read_pdu(0, 1)) == bytes((0x83, 0x0A))
            finally:
                c.close()
            assert s.stop() == 0
        assert any("upstream unreachable" in line for line in s.stderr_lines)


def test_pymodbus_drops_pipelined_requests_and_serve_goes_one_at_a_time() -> None:
    # pymodbus's TCP server (3.16) answers only the first of requests that
    # arrive together: serve sees a unit answer a later request and not an
    # earlier one, says so, and sends one at a time from then on
    expect = {a: [7 * (a + i) & 0xFFFF for i in range(3)] for a in range(1000)}
    with pymodbus_server("tcp") as port, Served("--tcp", f"127.0.0.1:{port}",
                                                "--timeout", "1") as s:
        c = RawClient(s.port)
        try:
            for _ in range(5):  # until pymodbus has taken some together (at once, as a rule)
                c.send(b"".join(mbap(tid, 1, read_pdu(3 * tid, 3)) for tid in range(6)))
                for _ in range(6):
                    tid, unit, pdu = c.reply()
                    assert unit == 1
                    # the right reply, or the gateway's 0x0B: never another request's
                    assert pdu == bytes((0x83, 0x0B)) or words(pdu) == expect[3 * tid], \
                        (tid, pdu)
                if any("one transaction at a time" in line for line in s.stderr_lines):
                    break
        finally:
            c.close()
        assert any("one transaction at a time from now" in line for line in s.stderr_lines)
        assert _many_clients_units(s.port, expect) == []
        assert s.stop() == 0


def _many_clients_units(port: int, expect: dict[int, list[int]]) -> list[str]:
    # pymodbus serves units 1 and 17 only: clients on those two
    failures: list[str] = []

    def one(k: int) -> None:
        unit = (1, 17)[k % 2]
        c = RawClient(port, timeout=30)
        try:
            for n in range(0, 30, 3):
                tids = {(k * 100 + n + j) & 0xFFFF: (k * 29 + (n + j) * 7) % 900
                        for j in range(3)}
                for tid, address in tids.items():
                    c.send(mbap(tid, unit, read_pdu(address, 3)))
                for _ in tids:
                    tid, runit, pdu = c.reply()
                    if runit != unit or tid not in tids or words(pdu) != expect[tids[tid]]:
                        failures.append(f"client {k}: tid {tid} unit {runit} {pdu.hex(' ')}")
                        return
        except Exception as e:  # said as a failure of this client
            failures.append(f"client {k}: {e!r}")
        finally:
            c.close()

    threads = [threading.Thread(target=one, args=(k,)) for k in range(16)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    assert not any(t.is_alive() for t in threads)
    return failures


def test_many_clients_pipelined_to_libmodbus(tmp_path: Path) -> None:
    # libmodbus's server reads one request at a time by its MBAP length, so
    # requests sent together wait their turn in its socket and all are answered
    exe = build_libmodbus_server(tmp_path)
    expect = {a: [3 * (a + i) & 0xFFFF for i in range(3)] for a in range(1000)}
    with libmodbus_server(exe, "tcp") as port, Served("--tcp", f"127.0.0.1:{port}",
                                                      "--timeout", "10") as s:
        assert _many_clients(s.port, clients=16, each=30, window=3, unit=17,
                             expect=expect) == []
        assert s.stop() == 0
    assert not any("one transaction at a time" in line for line in s.stderr_lines)


def test_max_inflight_out_of_range_is_one_line(device: OutOfOrder) -> None:
    from conftest import run_pymb
    r = run_pymb("serve", "--tcp", f"127.0.0.1:{device.port}", "--max-inflight", "0",
                 "--listen", "127.0.0.1:0", timeout=30)
    assert r.returncode == 2, r.stderr
    assert r.stderr.strip() == "pymb serve: --max-inflight must be 1..255, got 0"


def test_a_stop_drops_what_waits_for_a_silent_unit(device: OutOfOrder) -> None:
    with Served("--tcp", f"127.0.0.1:{device.port}", "--max-inflight", "2",
                "--timeout", "0.5") as s:
        c = RawClient(s.port)
        c.send(b"".join(mbap(i, SILENT_UNIT, read_pdu(i, 1)) for i in range(16)))  # 4 s
        wait_until(lambda: device.requests >= 2, "the first requests upstream")
        t = time.monotonic()
        assert s.stop() == 0
        assert time.monotonic() - t < 3.0  # not the 16 timeouts
        c.close()
    assert device.requests < 16


def test_the_reads_of_a_client_that_has_gone_are_not_sent(device: OutOfOrder) -> None:
    with Served("--tcp", f"127.0.0.1:{device.port}", "--max-inflight", "2",
                "--timeout", "0.5") as s:
        c = RawClient(s.port)
        c.send(b"".join(mbap(i, SILENT_UNIT, read_pdu(i, 1)) for i in range(16)))  # 4 s
        wait_until(lambda: device.requests >= 2, "the first requests upstream")
        c.close()
        time.sleep(1.5)  # three timeouts' worth: before, 6 more would have gone upstream
        assert device.requests <= 4
        assert s.stop() == 0
    assert f"{16 - device.requests} not sent (their clients had gone)" in s.stderr_lines[-1]


def test_a_reply_after_the_timeout_reaches_no_one(device: OutOfOrder) -> None:
    with Served("--tcp", f"127.0.0.1:{device.port}", "--timeout", "0.5") as s:
        c = RawClient(s.port)
        try:
            assert c.ask(1, LATE_UNIT, read_pdu(10, 2)) == bytes((0x83, 0x0B))
            # the late reply comes while these are asked: each gets its own
            deadline = time.monotonic() + LATE + 1.0
            tid = 2
            while time.monotonic() < deadline:
                assert words(c.ask(tid, 5, read_pdu(tid, 2))) == [_value(5, tid),
                                                                 _value(5, tid + 1)]
                tid += 1
        finally:
            c.close()
        assert s.stop() == 0


def test_max_inflight_is_refused_for_an_mbaps_upstream() -> None:
    from conftest import run_pymb
    r = run_pymb("serve", "--tcp", "mbaps://127.0.0.1:802", "--max-inflight", "2",
                 "--listen", "127.0.0.1:0", timeout=30)
    assert r.returncode == 2, r.stderr
    assert "--max-inflight needs --tcp HOST:PORT, a plain Modbus TCP upstream" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
