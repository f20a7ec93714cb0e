"""Modbus/TCP Security: docs/security.md's openssl steps run as written, then
``pymb serve --tls`` used by pymodbus's TLS client and Python's ssl: roles
from the certificates, refused certificates (expired, another CA, none, the
wrong name, TLS 1.1), and the role extension read from any bytes."""

from __future__ import annotations

import shlex
import socket
import ssl
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import run_pymb, wait_until
from docblocks import claim_one
from hypothesis import given
from hypothesis import strategies as st
from peers import PtyPeer
from servekit import RawClient, Served, mbap, read_pdu, words
from tlskit import make_certs
from wire_peers import pymodbus_server

import pymb
from pymb.serve.roles import CertificateError, role_of


@pytest.fixture(scope="module")
def certs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """docs/security.md's certificates and those that must be refused (tlskit)."""
    return make_certs(tmp_path_factory.mktemp("security"))


@pytest.fixture
def served(certs: Path) -> Iterator[tuple[Served, PtyPeer]]:
    block = claim_one("docs/security.md", "sh", how="run", contains="pymb serve")
    argv = shlex.split(block.text)
    assert argv[:2] == ["pymb", "serve"]
    with PtyPeer() as peer:
        args = [peer.port if a == "/dev/ttyUSB0" else str(certs / a) if a.endswith(
            (".pem", ".key")) else a for a in argv[2:]]
        i = args.index("--listen")
        assert args[i + 1] == "0.0.0.0:802"
        del args[i:i + 2]
        with Served(*args, listen="127.0.0.1:0") as s:
            yield s, peer
            assert s.stop() == 0


def _context(certs: Path, who: str | None, *, ca: Path | None = None) -> ssl.SSLContext:
    ctx = ssl.create_default_context(ssl.Purpose.SERVER_AUTH, cafile=str(ca or certs / "ca.pem"))
    if who is not None:
        base = certs / who if "/" not in who else Path(who)
        ctx.load_cert_chain(f"{base}.pem", f"{base}.key")
    return ctx


def _ask(ctx: ssl.SSLContext, port: int, pdu: bytes, *, name: str = "localhost") -> bytes:
    with socket.create_connection(("127.0.0.1", port), timeout=10) as raw, \
            ctx.wrap_socket(raw, server_hostname=name) as tls:
        tls.sendall(mbap(7, 1, pdu))
        buf = b""
        while len(buf) < 6 or len(buf) < 6 + int.from_bytes(buf[4:6], "big"):
            data = tls.recv(4096)
            if not data:
                raise ConnectionError("closed")
            buf += data
        assert buf[:2] == b"\x00\x07"
        return buf[7:]


def test_the_guides_pymodbus_client_reads_and_writes_as_operator(
        certs: Path, served: tuple[Served, PtyPeer]) -> None:
    s, peer = served
    block = claim_one("docs/security.md", "python", how="run", contains="pymodbus")
    code = block.text.replace("port=802", f"port={s.port}")
    r = subprocess.run([sys.executable, "-c", code], cwd=certs, capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "[0, 7]"
    assert peer.memory.holding[10] == 1234
    assert (1, bytes((6, 0, 10, 0x04, 0xD2))) in peer.requests


def test_a_viewer_reads_and_its_writes_are_refused_before_the_line(
        certs: Path, served: tuple[Served, PtyPeer]) -> None:
    s, peer = served
    viewer = _context(certs, "viewer")
    assert _ask(viewer, s.port, read_pdu(2, 1)) == bytes((3, 2, 0, 14))
    before = list(peer.requests)
    for pdu in (bytes((6, 0, 10, 0, 1)), bytes((0x10, 0, 10, 0, 1, 2, 0, 1)),
                bytes((5, 0, 1, 0xFF, 0)), bytes((0x16, 0, 1, 0, 0, 0, 1)),
                bytes((0x17, 0, 0, 0, 1, 0, 10, 0, 1, 2, 0, 1))):
        assert _ask(viewer, s.port, pdu) == bytes((pdu[0] | 0x80, 1))
    assert peer.requests == before  # not a byte of it reached the line
    operator = _context(certs, "operator")
    assert _ask(operator, s.port, bytes((6, 0, 11, 0, 5))) == bytes((6, 0, 11, 0, 5))


def test_a_viewer_sends_only_what_reads(certs: Path, served: tuple[Served, PtyPeer]) -> None:
    # Modbus/TCP Security: a role that may not write gets exception 01 for
    # whatever is not a read, not only for the write function codes: a
    # diagnostic that restarts the device (08/0001), silences it (08/0004)
    # or clears its counters (08/000A), CANopen's 2B/0D, user-defined codes.
    s, peer = served
    viewer = _context(certs, "viewer")
    before = list(peer.requests)
    for pdu in (bytes((8, 0, 1, 0, 0)), bytes((8, 0, 4, 0, 0)), bytes((8, 0, 0x0A, 0, 0)),
                bytes((8, 0, 0x14, 0, 0)), bytes((0x2B, 0x0D, 0, 0)), bytes((0x41, 1, 2)),
                bytes((0x64, 0))):
        assert _ask(viewer, s.port, pdu) == bytes((pdu[0] | 0x80, 1)), pdu.hex()
    assert peer.requests == before  # not a byte of it reached the line
    # What only reads goes to the line and comes back as the device answered.
    assert _ask(viewer, s.port, bytes((7,))) == bytes((7, 0x5A))
    assert _ask(viewer, s.port, bytes((0x11,)))[:2] == bytes((0x11, 11))
    # The pty peer frames no 08 or 2B (their length is told by silence), so
    # these reach the line and no reply comes: the gateway's 0B, not 01.
    for pdu in (bytes((8, 0, 0, 0x12, 0x34)), bytes((8, 0, 0x0B, 0, 0)),
                bytes((0x2B, 0x0E, 1, 0))):
        assert _ask(viewer, s.port, pdu) == bytes((pdu[0] | 0x80, 0x0B)), pdu.hex()
    # A write role may send what the viewer may not.
    operator = _context(certs, "operator")
    assert _ask(operator, s.port, bytes((8, 0, 1, 0, 0))) == bytes((0x88, 0x0B))
    assert _ask(operator, s.port, bytes((0x41, 1, 2))) == bytes((0xC1, 0x0B))


@pytest.mark.parametrize(("who", "said"), [
    ("expired", "the client's certificate was refused: certificate has expired"),
    ("other/operator", "the client's certificate was refused: unable to get local issuer "
                       "certificate"),
    (None, "the client gave no certificate"),
    ("plain", "the client does not speak TLS (a plain Modbus TCP client?)"),
])
def test_bad_client_certificates_are_refused_with_one_line(
        certs: Path, served: tuple[Served, PtyPeer], who: str | None, said: str) -> None:
    """Each refusal is one line that says why in words, not OpenSSL's codes."""
    s, _ = served
    if who == "plain":  # a Modbus TCP client at the TLS port
        with socket.create_connection(("127.0.0.1", s.port), timeout=10) as raw:
            raw.sendall(mbap(7, 1, read_pdu(0, 1)))
            assert raw.recv(4096) == b""
    else:
        ctx = _context(certs, str(certs / who) if who else None)
        with pytest.raises((ssl.SSLError, ConnectionError, OSError)):
            _ask(ctx, s.port, read_pdu(0, 1))
    wait_until(lambda: any("TLS refused" in line for line in s.stderr_lines),
               lambda: f"the refusal line (stderr: {s.stderr_lines})")
    refused = [line for line in s.stderr_lines if "TLS refused" in line]
    assert len(refused) == 1
    assert refused[0].endswith(f": TLS refused: {said}"), refused
    assert not any("Traceback" in line for line in s.stderr_lines)
    # the others are still served
    assert _ask(_context(certs, "viewer"), s.port, read_pdu(1, 1)) == bytes((3, 2, 0, 7))


def test_a_server_name_the_certificate_does_not_list_is_refused_by_the_client(
        certs: Path, served: tuple[Served, PtyPeer]) -> None:
    s, _ = served
    with pytest.raises(ssl.SSLCertVerificationError):
        _ask(_context(certs, "operator"), s.port, read_pdu(0, 1), name="gateway.example")


def test_tls_1_1_is_refused(certs: Path, served: tuple[Served, PtyPeer]) -> None:
    s, _ = served
    ctx = _context(certs, "operator")
    ctx.minimum_version = ssl.TLSVersion.MINIMUM_SUPPORTED
    ctx.maximum_version = ssl.TLSVersion.TLSv1_1
    with pytest.raises((ssl.SSLError, ConnectionError, OSError)):
        _ask(ctx, s.port, read_pdu(0, 1))


def test_the_role_is_read_from_the_certificates(certs: Path) -> None:
    def der(name: str) -> bytes:
        return ssl.PEM_cert_to_DER_cert((certs / f"{name}.pem").read_text())
    assert role_of(der("operator")) == "operator"
    assert role_of(der("viewer")) == "viewer"
    assert role_of(der("server")) is None
    assert role_of(der("ca")) is None


@given(st.binary(max_size=300))
def test_any_bytes_give_a_role_none_or_a_certificate_error(data: bytes) -> None:
    try:
        role = role_of(data)
    except CertificateError:
        return
    assert role is None or isinstance(role, str)


def test_a_truncated_certificate_is_a_certificate_error(certs: Path) -> None:
    whole = ssl.PEM_cert_to_DER_cert((certs / "operator.pem").read_text())
    for n in range(0, len(whole), 7):
        try:
            role_of(whole[:n])
        except CertificateError:
            continue
        raise AssertionError(f"{n} bytes of {len(whole)} read as a certificate")


def test_an_mbaps_upstream_with_its_own_ca_and_client_certificate(certs: Path) -> None:
    # pymodbus's TLS server wants a client certificate signed by ca.pem: pymb
    # serve shows it --upstream-cert, and checks the server's by --upstream-ca.
    client = ["--upstream-ca", str(certs / "ca.pem"), "--upstream-cert",
              str(certs / "operator.pem"), "--upstream-key", str(certs / "operator.key")]
    with pymodbus_server("tls", str(certs)) as port, \
            Served("--tcp", f"mbaps://localhost:{port}", *client) as s:
        c = RawClient(s.port)
        try:
            assert words(c.ask(5, 1, read_pdu(0, 3))) == [0, 7, 14]
        finally:
            c.close()
        assert s.stop() == 0


@pytest.mark.parametrize(("args", "said"), [
    (["--tcp", "127.0.0.1:502", "--upstream-ca", "ca.pem"],
     "--upstream-ca/--upstream-cert/--upstream-key/--upstream-server-name need --tcp mbaps://"),
    (["--tcp", "mbaps://127.0.0.1", "--upstream-ca", "nope.pem"],
     "--upstream-ca 'nope.pem': no such file"),
    (["--tcp", "mbaps://127.0.0.1", "--upstream-key", "operator.key"],
     "--upstream-key needs --upstream-cert"),
])
def test_upstream_tls_mistakes_are_one_line(certs: Path, args: list[str], said: str) -> None:
    r = run_pymb("serve", *args, "--listen", "127.0.0.1:0", cwd=certs, timeout=30)
    assert r.returncode == 2, r.stderr
    assert r.stderr.startswith(f"pymb serve: {said}"), r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def test_with_tls_it_listens_on_802_where_mbaps_clients_go(certs: Path) -> None:
    # No --listen: Modbus/TCP Security's port, the one TcpClient(tls=...) and
    # mbaps://HOST take when none is given.
    server = ["--tls", "--cert", str(certs / "server.pem"), "--key", str(certs / "server.key"),
              "--ca", str(certs / "ca.pem")]
    with pymodbus_server("tcp") as port, \
            Served("--tcp", f"127.0.0.1:{port}", *server, listen="") as s:
        assert s.port == 802
        tls = pymb.TlsConfig(ca=certs / "ca.pem", cert=certs / "operator.pem",
                             key=certs / "operator.key")
        with pymb.TcpClient("localhost", tls=tls, slave=1) as c:
            assert list(c.read_holding_registers(0, 3)) == [0, 7, 14]
        assert s.stop() == 0
