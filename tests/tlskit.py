"""Certificates for the Modbus/TCP Security tests, made with openssl as
docs/security.md says (its blocks run as written), and the ones that must
be refused: an expired client and server certificate (made under faketime),
and a CA, clients and a server of another plant."""

from __future__ import annotations

import re
import shutil
import socket
import ssl
import subprocess
import threading
from collections.abc import Callable, Iterable
from pathlib import Path

import pytest
from docblocks import claim

__all__ = ["TlsPeer", "make_certs", "sh_lines"]


def sh_lines(block_text: str, cwd: Path, prefix: list[str] | None = None) -> None:
    """Run each line of a shell block in ``cwd`` (each must succeed)."""
    for line in block_text.splitlines():
        r = subprocess.run([*(prefix or []), "sh", "-c", line], cwd=cwd, capture_output=True,
                           text=True, timeout=60)
        assert r.returncode == 0, f"{line}\n{r.stderr}"


def make_certs(d: Path) -> Path:
    """docs/security.md's certificates in ``d``, plus ``expired.pem``/``.key``
    (a client, operator role, expired in 2020), ``server-expired.pem``/``.key``
    (the server's names, expired in 2020) and ``other/`` (another CA with its
    own server and clients)."""
    ca_block, server_block, clients_block = claim("docs/security.md", "sh", how="run",
                                                  contains="openssl")
    for block in (ca_block, server_block, clients_block):
        sh_lines(block.text, d)
    if shutil.which("faketime") is None:
        pytest.fail("faketime is not installed: .ci/setup installs it")
    operator_lines = "".join(line + "\n" for line in clients_block.lines() if "operator" in line)
    old = operator_lines.replace("operator", "expired").replace("-days 825", "-days 1")
    sh_lines(old, d, ["faketime", "2020-01-01 00:00:00"])
    old_server = re.sub(r"\bserver\.", "server-expired.", server_block.text).replace(
        "-days 825", "-days 1")
    sh_lines(old_server, d, ["faketime", "2020-01-01 00:00:00"])
    other = d / "other"
    other.mkdir()
    for block in (ca_block, server_block, clients_block):
        sh_lines(block.text, other)
    return d


class TlsPeer:
    """A scripted Modbus/TCP Security server on 127.0.0.1 (Python's ssl, not
    pymb's): ``d``'s server certificate, client certificates signed by
    ``d/ca.pem`` required. Each request (a whole MBAP frame) goes to
    ``script(index, request)``, whose frames are sent one by one; with
    ``close_after_reply`` the connection is closed after each answer.
    ``version`` offers that TLS version only. ``requests`` keeps every
    request, ``connections`` counts accepts."""

    def __init__(self, d: Path, script: Callable[[int, bytes], Iterable[bytes]], *,
                 close_after_reply: bool = False,
                 version: ssl.TLSVersion | None = None) -> None:
        self.ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
        if version is not None:  # only this version (an old one: at OpenSSL's level 0)
            self.ctx.set_ciphers("DEFAULT:@SECLEVEL=0")
            self.ctx.minimum_version = self.ctx.maximum_version = version
        self.ctx.load_cert_chain(d / "server.pem", d / "server.key")
        self.ctx.load_verify_locations(d / "ca.pem")
        self.ctx.verify_mode = ssl.CERT_REQUIRED
        self.script = script
        self.close_after_reply = close_after_reply
        self.requests: list[bytes] = []
        self.connections = 0
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.listener.settimeout(0.2)
        self.port: int = self.listener.getsockname()[1]
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                raw, _ = self.listener.accept()
            except TimeoutError:
                continue
            raw.settimeout(10)
            try:
                with self.ctx.wrap_socket(raw, server_side=True) as conn:
                    self.connections += 1
                    self._serve(conn)
            except (OSError, ssl.SSLError):
                continue

    def _serve(self, conn: ssl.SSLSocket) -> None:
        buf = b""
        while not self._stop.is_set():
            while len(buf) < 6 or len(buf) < 6 + int.from_bytes(buf[4:6], "big"):
                data = conn.recv(4096)
                if not data:
                    return
                buf += data
            n = 6 + int.from_bytes(buf[4:6], "big")
            adu, buf = buf[:n], buf[n:]
            self.requests.append(adu)
            for frame in self.script(len(self.requests) - 1, adu):
                conn.sendall(frame)
            if self.close_after_reply:
                return

    def __enter__(self) -> TlsPeer:
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(10)
        self.listener.close()
