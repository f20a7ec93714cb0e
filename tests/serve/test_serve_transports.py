"""``pymb serve --ascii --port PATH`` and ``pymb serve --udp HOST:PORT``:
Modbus TCP clients in front of a Modbus ASCII line (pymodbus's ASCII server
on a pseudo-terminal) or a Modbus UDP device (pymodbus's UDP server)
(tests/pymodbus_server.py: holding register a holds 7 * a, units 1 and 17)."""

from __future__ import annotations

import json
import socket
import struct
import threading

from conftest import run_pymb
from servekit import RawClient, Served, mbap, read_pdu, words
from wire_peers import pymodbus_peer

from pymb.sim import Simulator


def test_clients_share_an_ascii_line() -> None:
    with pymodbus_peer("ascii") as pty, \
            Served("--ascii", "--port", pty, "--baud", "19200", "--timeout", "1") as served:
        a, b = RawClient(served.port), RawClient(served.port)
        try:
            assert words(a.ask(7, 17, read_pdu(0, 5))) == [0, 7, 14, 21, 28]
            assert words(b.ask(900, 1, read_pdu(10, 2))) == [70, 77]
            # A write, then its value read back by the other client.
            write = struct.pack(">BHH", 6, 500, 4242)
            assert a.ask(8, 17, write) == write
            assert words(b.ask(901, 17, read_pdu(500, 1))) == [4242]
            # The device's exception passes through, and the line stays in step.
            assert a.ask(9, 17, read_pdu(990, 20)) == bytes((0x83, 0x02))
            assert words(a.ask(10, 17, read_pdu(3, 1))) == [21]
            # Both clients at once: each gets its own answers.
            wrong: list[str] = []

            def worker(c: RawClient, unit: int, base: int) -> None:
                for k in range(20):
                    got = words(c.ask(base + k, unit, read_pdu(k, 2)))
                    if got != [7 * k, 7 * k + 7]:
                        wrong.append(f"{unit}: {k}: {got}")

            threads = [threading.Thread(target=worker, args=(a, 17, 100)),
                       threading.Thread(target=worker, args=(b, 1, 300))]
            for t in threads:
                t.start()
            for t in threads:
                t.join(60)
            assert not wrong
        finally:
            a.close()
            b.close()
        assert served.stop() == 0


def test_a_udp_device_upstream() -> None:
    with pymodbus_peer("udp") as port, \
            Served("--udp", f"127.0.0.1:{port}", "--timeout", "1") as served:
        c = RawClient(served.port)
        try:
            assert words(c.ask(1, 17, read_pdu(4, 2))) == [28, 35]
            assert c.ask(2, 17, read_pdu(990, 20)) == bytes((0x83, 0x02))
        finally:
            c.close()
        assert served.stop() == 0


def test_a_silent_udp_device_is_asked_three_times_then_answered_0x0b() -> None:
    # docs/serve.md: over UDP a request is sent again twice, each send waits
    # --timeout, and only then is the client answered 0x0B.
    sink = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sink.bind(("127.0.0.1", 0))
    sink.settimeout(30)
    try:
        with Served("--udp", f"127.0.0.1:{sink.getsockname()[1]}", "--timeout", "0.3") as s:
            c = RawClient(s.port, timeout=30)
            try:
                c.send(mbap(9, 5, read_pdu(0, 2)))
                heard = [sink.recv(300) for _ in range(3)]
                assert heard[0] == heard[1] == heard[2]  # the same transaction id each time
                tid, unit, pdu = c.reply()
                assert (tid, unit, pdu) == (9, 5, bytes((0x83, 0x0B)))
            finally:
                c.close()
            assert s.stop() == 0
    finally:
        sink.close()


def test_a_scan_through_serve_finds_the_devices_behind_it_and_no_phantoms() -> None:
    # The gateway answers 0x0B for every silent address: silence, not a device.
    with Simulator(["coolpro:40", "hub:7"], seed=5) as sim, \
            Served("--port", sim.port, "--baud", "9600", "--timeout", "0.3") as served:
        done = run_pymb("scan", "--tcp", f"127.0.0.1:{served.port}", "--timeout", "0.6",
                        "--range", "5-8,40,41", "--json", timeout=120)
        assert done.returncode == 0, done.stderr
        found = {d["address"]: d["device"] for d in json.loads(done.stdout)["found"]}
        assert found == {7: "hub", 40: "coolpro"}
