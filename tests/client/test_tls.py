"""Modbus/TCP Security on the client side (``TcpClient(tls=...)``, its asyncio
twin): against pymodbus's TLS server, ``pymb serve --tls`` and a scripted TLS
server on Python's ssl; certificates made with openssl by tests/tlskit.py.
Refused server certificates (expired, another CA, another name), a refused
client, a plain port; stale replies dropped and reads resent as over plain
TCP."""

from __future__ import annotations

import asyncio
import signal
import socket
import ssl
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import PYMB_ENV
from docblocks import assert_shaped, claim_one
from peerkit import mbap
from peers import PtyPeer
from servekit import Served
from tlskit import TlsPeer, make_certs
from wire_peers import answer_read, pymodbus_server, tcp_request

import pymb
import pymb.aio


@pytest.fixture(scope="module")
def certs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_certs(tmp_path_factory.mktemp("tls"))


def _tls(certs: Path, who: str | None = "operator", *, ca: str = "ca.pem",
         **kw: object) -> pymb.TlsConfig:
    if who is None:
        return pymb.TlsConfig(ca=certs / ca, **kw)  # type: ignore[arg-type]
    return pymb.TlsConfig(ca=certs / ca, cert=certs / f"{who}.pem", key=certs / f"{who}.key",
                          **kw)  # type: ignore[arg-type]


@pytest.fixture
def served(certs: Path) -> Iterator[tuple[Served, PtyPeer]]:
    """``pymb serve --tls`` in front of a pty peer, operator may write."""
    with PtyPeer() as peer, Served("--port", peer.port, "--tls",
                                   "--cert", str(certs / "server.pem"),
                                   "--key", str(certs / "server.key"),
                                   "--ca", str(certs / "ca.pem"),
                                   "--write-roles", "operator") as s:
        yield s, peer


def test_pymodbus_tls_server_reads_writes_and_exceptions(certs: Path) -> None:
    with pymodbus_server("tls", str(certs)) as port, \
            pymb.TcpClient("127.0.0.1", port, tls=_tls(certs, server_name="localhost"),
                           slave=1, timeout=5) as c:
        assert list(c.read_holding_registers(0, 4)) == [0, 7, 14, 21]
        assert list(c.read_input_registers(3, 2)) == [40003, 40004]
        assert list(c.read_coils(0, 4)) == [0, 1, 0, 1]
        c.write_registers(10, [1, 2, 3])
        assert list(c.read_holding_registers(10, 3)) == [1, 2, 3]
        with pytest.raises(pymb.IllegalDataAddress):
            c.read_holding_registers(5000, 2)
        assert list(c.read_holding_registers(999, 1)) == [(7 * 999) & 0xFFFF]
        # 250 registers: two requests on the one TLS connection
        want = [(7 * a) & 0xFFFF for a in range(250)]
        want[10:13] = [1, 2, 3]
        assert list(c.read_holding_registers(0, 250)) == want
        assert c.connections == 1


def test_pymodbus_tls_server_without_a_client_certificate(certs: Path) -> None:
    with pymodbus_server("tls", str(certs)) as port, \
            pymb.TcpClient("127.0.0.1", port, tls=_tls(certs, None), slave=1, timeout=5) as c, \
            pytest.raises(pymb.TlsError, match="refuse this client or its certificate"):
        c.read_holding_registers(0, 1)


def test_pymb_serve_tls_roles_from_this_clients_certificate(
        certs: Path, served: tuple[Served, PtyPeer]) -> None:
    s, peer = served
    with pymb.TcpClient("127.0.0.1", s.port, tls=_tls(certs), slave=1, timeout=5) as c:
        assert list(c.read_holding_registers(0, 3)) == [0, 7, 14]
        c.write_register(10, 1234)
        assert peer.memory.holding[10] == 1234
    with pymb.TcpClient("127.0.0.1", s.port, tls=_tls(certs, "viewer"), slave=1,
                        timeout=5) as c:
        assert list(c.read_holding_registers(10, 1)) == [1234]
        with pytest.raises(pymb.IllegalFunction):
            c.write_register(10, 1)
    assert peer.memory.holding[10] == 1234


@pytest.mark.parametrize(("server", "config", "words"), [
    ("server-expired", {}, "certificate has expired"),
    ("other/server", {}, "not signed by the CA given"),
    ("server", {"server_name": "gateway.example"},
     "Hostname mismatch, certificate is not valid for 'gateway.example'"),
])
def test_refused_server_certificates_fail_the_connect_in_one_line(
        certs: Path, server: str, config: dict[str, str], words: str) -> None:
    with PtyPeer() as peer, Served("--port", peer.port, "--tls",
                                   "--cert", str(certs / f"{server}.pem"),
                                   "--key", str(certs / f"{server}.key"),
                                   "--ca", str(certs / "ca.pem")) as s:
        c = pymb.TcpClient("127.0.0.1", s.port, tls=_tls(certs, **config), slave=1, timeout=5)
        with pytest.raises(pymb.TlsError) as e:
            c.connect()
        msg = str(e.value)
        if server == "server-expired":
            assert_shaped(claim_one("docs/security.md", "text", how="compare",
                                    contains="certificate has expired"), [msg])
        assert msg == (f"cannot open 127.0.0.1:{s.port}: the server's certificate was "
                       f"refused: {msg.split('refused: ', 1)[1]}")
        assert words in msg
        assert "\n" not in msg
        assert not c.connected
        assert peer.requests == []  # nothing reached the line


def test_a_client_certificate_made_for_a_server_is_refused_in_words(
        certs: Path, served: tuple[Served, PtyPeer]) -> None:
    s, peer = served
    tls = pymb.TlsConfig(ca=certs / "ca.pem", cert=certs / "server.pem",
                         key=certs / "server.key")
    with pytest.raises(pymb.TlsError) as e, \
            pymb.TcpClient("127.0.0.1", s.port, tls=tls, slave=1, timeout=5) as c:
        c.read_holding_registers(0, 1)
    assert str(e.value).endswith(
        "the server refused this client's certificate (not made for a client: its extended "
        "key usage)"), str(e.value)
    assert peer.requests == []


def test_the_guides_pymb_client_reads_and_writes_as_operator(
        certs: Path, served: tuple[Served, PtyPeer]) -> None:
    s, peer = served
    block = claim_one("docs/security.md", "python", how="run", contains="pymb.TlsConfig")
    code = block.text.replace('TcpClient("localhost", tls=tls',
                              f'TcpClient("localhost", {s.port}, tls=tls')
    assert code != block.text
    r = subprocess.run([sys.executable, "-c", code], cwd=certs, capture_output=True, text=True,
                       timeout=60, env=PYMB_ENV)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "[0, 7]"
    assert peer.memory.holding[10] == 1234


def test_check_hostname_off_checks_the_signature_only(certs: Path,
                                                      served: tuple[Served, PtyPeer]) -> None:
    s, _ = served
    tls = _tls(certs, server_name="gateway.example", check_hostname=False)
    with pymb.TcpClient("127.0.0.1", s.port, tls=tls, slave=1, timeout=5) as c:
        assert list(c.read_holding_registers(1, 1)) == [7]
    other = _tls(certs, ca="other/ca.pem", check_hostname=False)
    with pytest.raises(pymb.TlsError, match="not signed by the CA given"):
        pymb.TcpClient("127.0.0.1", s.port, tls=other, slave=1, timeout=5).connect()


def test_a_refusal_names_the_system_cas_when_no_ca_was_given(
        certs: Path, served: tuple[Served, PtyPeer]) -> None:
    s, _ = served
    system = pymb.TlsConfig(cert=certs / "operator.pem", key=certs / "operator.key",
                            server_name="localhost")
    with pytest.raises(pymb.TlsError) as e:
        pymb.TcpClient("127.0.0.1", s.port, tls=system, slave=1, timeout=5).connect()
    msg = str(e.value)
    assert msg.endswith("(not signed by any of the system's trusted CAs)"), msg
    assert "CA given" not in msg
    given = _tls(certs, ca="other/ca.pem", server_name="localhost")
    with pytest.raises(pymb.TlsError) as e:
        pymb.TcpClient("127.0.0.1", s.port, tls=given, slave=1, timeout=5).connect()
    assert str(e.value).endswith("(not signed by the CA given)"), str(e.value)


def test_a_plain_modbus_tcp_port_is_named(certs: Path) -> None:
    # A plain Modbus TCP server takes the ClientHello for a bad request and
    # answers with an exception frame.
    with socket.create_server(("127.0.0.1", 0)) as listener:
        port = listener.getsockname()[1]

        def answer() -> None:
            conn, _ = listener.accept()
            with conn:
                conn.settimeout(10)
                conn.recv(4096)
                conn.sendall(mbap(0, 1, bytes((0x83, 0x01))))
                conn.recv(4096)  # until the client goes

        t = threading.Thread(target=answer, daemon=True)
        t.start()
        c = pymb.TcpClient("127.0.0.1", port, tls=_tls(certs), slave=1, timeout=5)
        with pytest.raises(pymb.TlsError) as e:
            c.connect()
        assert str(e.value) == (f"cannot open 127.0.0.1:{port}: the server does not speak TLS "
                                "there (a plain Modbus TCP port?)")
        assert not c.connected
        t.join(10)


def test_a_stale_reply_inside_tls_is_dropped_by_its_transaction_id(certs: Path) -> None:
    def script(i: int, adu: bytes) -> list[bytes]:
        tid, unit, _pdu = tcp_request(adu)
        old = struct.pack(">HHHB", (tid - 1) & 0xFFFF, 0, 5, unit) + bytes((3, 2, 0, 99))
        return [old + answer_read(adu, [i])]  # one TLS record: the stale reply first

    with TlsPeer(certs, script) as peer, \
            pymb.TcpClient("127.0.0.1", peer.port, tls=_tls(certs, server_name="localhost"),
                           slave=1, timeout=5) as c:
        assert [c.read_holding_registers(0, 1)[0] for _ in range(4)] == [0, 1, 2, 3]


def test_a_read_is_resent_when_the_server_closes_after_each_reply(certs: Path) -> None:
    with TlsPeer(certs, lambda i, adu: [answer_read(adu, [i])],
                 close_after_reply=True) as peer, \
            pymb.TcpClient("127.0.0.1", peer.port, tls=_tls(certs, server_name="localhost"),
                           slave=1, timeout=5) as c:
        assert [c.read_holding_registers(0, 1)[0] for _ in range(3)] == [0, 1, 2]
        assert c.connections == 3
        assert c.resends == 2
        assert peer.connections == 3


def test_a_silent_tls_server_times_out_within_the_timeout(certs: Path) -> None:
    with TlsPeer(certs, lambda i, adu: [] if i == 0 else [answer_read(adu, [i])]) as peer, \
            pymb.TcpClient("127.0.0.1", peer.port, tls=_tls(certs, server_name="localhost"),
                           slave=1, timeout=0.5) as c:
        with pytest.raises(pymb.ModbusTimeout):
            c.read_holding_registers(0, 1)
        c.timeout = 5
        assert list(c.read_holding_registers(0, 1)) == [1]


def test_close_from_another_thread_ends_a_tls_wait_at_once(certs: Path) -> None:
    with TlsPeer(certs, lambda i, adu: [] if i == 0 else [answer_read(adu, [i])]) as peer, \
            pymb.TcpClient("127.0.0.1", peer.port, tls=_tls(certs, server_name="localhost"),
                           slave=1, timeout=5) as c:
        out: list[BaseException] = []

        def wait() -> None:
            with pytest.raises(pymb.ModbusConnectionError) as ei:
                c.read_holding_registers(0, 1)
            out.append(ei.value)

        t = threading.Thread(target=wait)
        t.start()
        time.sleep(0.3)
        t0 = time.monotonic()
        c.close()
        t.join(10)
        assert time.monotonic() - t0 < 1.5  # not the read's 5 s timeout
        assert "the client was closed while this request waited" in str(out[0])
        c.connect()  # a new connection, a new TLS session
        assert list(c.read_holding_registers(0, 1)) == [1]


def test_asyncio_cancelled_mid_reply_the_next_read_gets_its_own(certs: Path) -> None:
    def script(i: int, adu: bytes) -> Iterator[bytes]:
        reply = answer_read(adu, [100 + i])
        if i == 0:  # half a record's worth now, the rest 0.3 s later
            yield reply[:5]
            time.sleep(0.3)
        yield reply[5:] if i == 0 else reply

    async def main(port: int) -> None:
        async with pymb.aio.AsyncTcpClient("127.0.0.1", port, slave=1, timeout=2,
                                           tls=_tls(certs, server_name="localhost")) as c:
            first = asyncio.ensure_future(c.read_holding_registers(0, 1))
            while not peer.requests:
                await asyncio.sleep(0.005)
            first.cancel()
            assert list(await c.read_holding_registers(1, 1)) == [101]
            assert c.connections == 1

    with TlsPeer(certs, script) as peer:
        asyncio.run(main(peer.port))
        assert len(peer.requests) == 2


def test_asyncio_twin(certs: Path, served: tuple[Served, PtyPeer]) -> None:
    s, _ = served

    async def main() -> list[int]:
        async with pymb.aio.AsyncTcpClient("127.0.0.1", s.port, tls=_tls(certs), slave=1,
                                           timeout=5) as c:
            assert c.tls is not None
            assert c.tcp_port == s.port
            return list(await c.read_holding_registers(0, 2))

    assert asyncio.run(main()) == [0, 7]


def test_config_mistakes_are_invalid_arguments(certs: Path, tmp_path: Path) -> None:
    with pytest.raises(pymb.InvalidArgument, match="no such file"):
        pymb.TlsConfig(ca=tmp_path / "nope.pem")
    with pytest.raises(pymb.InvalidArgument, match="without its certificate"):
        pymb.TlsConfig(key=certs / "operator.key")
    with pytest.raises(pymb.InvalidArgument, match="is not the private key of"):
        pymb.TlsConfig(ca=certs / "ca.pem", cert=certs / "operator.pem",
                       key=certs / "viewer.key")
    with pytest.raises(pymb.InvalidArgument, match="not a PEM"):
        pymb.TlsConfig(ca=certs / "server.ext")
    with pytest.raises(pymb.InvalidArgument, match="TlsConfig"):
        pymb.TcpClient("127.0.0.1", tls="yes")  # type: ignore[arg-type]
    assert pymb.TcpClient("127.0.0.1", tls=_tls(certs)).tcp_port == 802
    assert pymb.TcpClient("127.0.0.1").tcp_port == 502


def test_a_signal_handler_that_raises_stops_a_tls_wait(certs: Path) -> None:
    class Stop(Exception):
        pass

    def handler(signum: int, frame: object) -> None:
        raise Stop

    old = signal.signal(signal.SIGALRM, handler)
    try:
        with TlsPeer(certs, lambda i, adu: [] if i == 0 else [answer_read(adu, [i])]) as peer, \
                pymb.TcpClient("127.0.0.1", peer.port, slave=1, timeout=20,
                               tls=_tls(certs, server_name="localhost")) as c:
            t0 = time.monotonic()
            signal.setitimer(signal.ITIMER_REAL, 0.3)
            with pytest.raises(Stop):
                c.read_holding_registers(0, 1)
            assert time.monotonic() - t0 < 10
            # the line owes its quiet window, then answers the next request
            c.timeout = 0.5
            assert list(c.read_holding_registers(0, 1)) == [1]
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


@pytest.mark.filterwarnings("ignore::DeprecationWarning")  # ssl.TLSVersion.TLSv1_1
def test_tls_1_2_is_taken_and_1_1_refused(certs: Path) -> None:
    with TlsPeer(certs, lambda i, adu: [answer_read(adu, [i])],
                 version=ssl.TLSVersion.TLSv1_2) as peer, \
            pymb.TcpClient("127.0.0.1", peer.port, tls=_tls(certs, server_name="localhost"),
                           slave=1, timeout=5) as c:
        assert list(c.read_holding_registers(0, 1)) == [0]
    with TlsPeer(certs, lambda i, adu: [answer_read(adu, [i])],
                 version=ssl.TLSVersion.TLSv1_1) as peer:
        c = pymb.TcpClient("127.0.0.1", peer.port, tls=_tls(certs, server_name="localhost"),
                           slave=1, timeout=5)
        with pytest.raises(pymb.TlsError) as e:
            c.connect()
        assert "TLS" in str(e.value)
        assert peer.requests == []


@pytest.mark.parametrize("answer", ["close", "silence"])
def test_a_server_that_closes_or_stays_silent_in_the_handshake(certs: Path, answer: str) -> None:
    with socket.create_server(("127.0.0.1", 0)) as listener:
        port = listener.getsockname()[1]
        done = threading.Event()

        def serve() -> None:
            conn, _ = listener.accept()
            with conn:
                conn.settimeout(10)
                conn.recv(4096)  # the ClientHello
                if answer == "silence":
                    done.wait(10)

        t = threading.Thread(target=serve, daemon=True)
        t.start()
        c = pymb.TcpClient("127.0.0.1", port, tls=_tls(certs), slave=1, timeout=0.5)
        t0 = time.monotonic()
        with pytest.raises(pymb.TlsError) as e:
            c.connect()
        done.set()
        words = ("closed the connection during the TLS handshake" if answer == "close"
                 else "the TLS handshake did not finish within the timeout")
        assert words in str(e.value)
        assert time.monotonic() - t0 < 5
        t.join(10)
