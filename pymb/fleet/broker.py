"""Debian's mosquitto, started on a free 127.0.0.1 port and stopped by its PID.

For the tests, ``pymb demo --mqtt`` and ``pymb bench --sections fleet``:
plain, TLS (certificates made here with ``openssl``) and a password file
(``mosquitto_passwd``); persistence on, so a restart keeps the sessions and
queued messages of subscribers that asked for them. :meth:`Mosquitto.pause`
and :meth:`resume` stall it (SIGSTOP / SIGCONT) as a dead network would.
"""

from __future__ import annotations

import contextlib
import os
import pwd
import shutil
import signal
import socket
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

__all__ = ["Certificates", "Mosquitto", "find_mosquitto", "free_port", "make_certificates"]


def find_mosquitto(tool: str = "mosquitto") -> str | None:
    """The path of mosquitto (or a companion tool), also where Debian puts it."""
    return shutil.which(tool) or next(
        (p for p in (f"/usr/sbin/{tool}", f"/usr/bin/{tool}") if os.access(p, os.X_OK)), None)


def free_port() -> int:
    """A TCP port free on 127.0.0.1 right now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass(frozen=True)
class Certificates:
    """A CA, a server certificate for 127.0.0.1/localhost and a client certificate."""

    ca: str
    server_cert: str
    server_key: str
    client_cert: str
    client_key: str


def _openssl(*args: str, cwd: Path) -> None:
    subprocess.run(["openssl", *args], cwd=cwd, check=True, capture_output=True, timeout=60)


def make_certificates(directory: str | os.PathLike[str]) -> Certificates:
    """A fresh CA and the certificates it signs (RSA 2048, one day), with openssl."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    _openssl("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "2", "-subj",
             "/CN=pymb test CA", "-keyout", "ca.key", "-out", "ca.pem", cwd=d)
    (d / "server.ext").write_text("subjectAltName=IP:127.0.0.1,DNS:localhost\n")
    for who, cn in (("server", "127.0.0.1"), ("client", "pymb-client")):
        _openssl("req", "-newkey", "rsa:2048", "-nodes", "-subj", f"/CN={cn}",
                 "-keyout", f"{who}.key", "-out", f"{who}.csr", cwd=d)
        ext = ["-extfile", "server.ext"] if who == "server" else []
        _openssl("x509", "-req", "-in", f"{who}.csr", "-CA", "ca.pem", "-CAkey", "ca.key",
                 "-CAcreateserial", "-days", "2", "-out", f"{who}.pem", *ext, cwd=d)
    return Certificates(str(d / "ca.pem"), str(d / "server.pem"), str(d / "server.key"),
                        str(d / "client.pem"), str(d / "client.key"))


class Mosquitto:
    """One mosquitto process on 127.0.0.1.

    ``tls``: certificates (the broker then speaks TLS only);
    ``require_client_cert``: reject clients without a certificate the CA signed;
    ``users``: name -> password (a password file; anonymous clients refused);
    ``extra``: more lines of its configuration (``acl_file PATH``,
    ``message_size_limit BYTES``), read again on :meth:`reload`.
    """

    def __init__(self, directory: str | os.PathLike[str], *, port: int | None = None,
                 tls: Certificates | None = None, require_client_cert: bool = False,
                 users: dict[str, str] | None = None, extra: tuple[str, ...] = ()) -> None:
        exe = find_mosquitto()
        if exe is None:
            raise FileNotFoundError("mosquitto is not installed (apt-get install mosquitto)")
        self.exe = exe
        self.dir = Path(directory)
        self.dir.mkdir(parents=True, exist_ok=True)
        self.port = port or free_port()
        self.tls = tls
        self.proc: subprocess.Popen[bytes] | None = None
        # as root, mosquitto would switch to the user "mosquitto", which cannot read
        # the files made here: it stays the user who started it
        lines = [f"user {pwd.getpwuid(os.getuid()).pw_name}",
                 f"listener {self.port} 127.0.0.1",
                 "persistence true", f"persistence_location {self.dir}/",
                 "autosave_interval 1", f"log_dest file {self.dir / 'mosquitto.log'}",
                 "log_type error", "log_type warning", "log_type notice",
                 "log_type information", "max_queued_messages 0",
                 "queue_qos0_messages true"]
        if users:
            pw = self.dir / "passwd"
            pw.write_text("")
            tool = find_mosquitto("mosquitto_passwd") or "mosquitto_passwd"
            for name, password in users.items():
                subprocess.run([tool, "-b", str(pw), name, password], check=True,
                               capture_output=True, timeout=30)
            lines += ["allow_anonymous false", f"password_file {pw}"]
        else:
            lines.append("allow_anonymous true")
        if tls is not None:
            lines += [f"cafile {tls.ca}", f"certfile {tls.server_cert}",
                      f"keyfile {tls.server_key}",
                      f"require_certificate {'true' if require_client_cert else 'false'}"]
        lines += extra
        self.extra = tuple(extra)
        self.conf = self.dir / "mosquitto.conf"
        self.conf.write_text("\n".join(lines) + "\n")

    @property
    def url(self) -> str:
        """``mqtt://127.0.0.1:PORT`` (``mqtts://`` with TLS)."""
        return f"{'mqtts' if self.tls else 'mqtt'}://127.0.0.1:{self.port}"

    @property
    def pid(self) -> int | None:
        """The broker's process id while it runs."""
        return None if self.proc is None else self.proc.pid

    def start(self, timeout: float = 15.0) -> None:
        """Start it and wait until it accepts connections."""
        if self.proc is not None:
            raise RuntimeError("mosquitto is already running")
        self.proc = subprocess.Popen([self.exe, "-c", str(self.conf)],
                                     stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        deadline = time.monotonic() + timeout
        while True:
            if self.proc.poll() is not None:
                err = self.proc.stderr.read().decode(errors="replace") if self.proc.stderr \
                    else ""
                log = self.dir / "mosquitto.log"
                err += log.read_text(errors="replace")[-2000:] if log.exists() else ""
                self.proc = None
                raise RuntimeError(f"mosquitto exited at start: {err.strip()}")
            with socket.socket() as s:
                s.settimeout(0.5)
                if s.connect_ex(("127.0.0.1", self.port)) == 0:
                    return
            if time.monotonic() > deadline:
                self.stop()
                raise RuntimeError(f"mosquitto did not listen on port {self.port}")
            time.sleep(0.05)

    def stop(self) -> None:
        """Stop it by its PID (SIGTERM, then SIGKILL after 10 s)."""
        p, self.proc = self.proc, None
        if p is None:
            return
        with contextlib.suppress(ProcessLookupError):
            os.kill(p.pid, signal.SIGCONT)  # a paused broker cannot act on SIGTERM
            os.kill(p.pid, signal.SIGTERM)
        try:
            p.wait(10)
        except subprocess.TimeoutExpired:
            os.kill(p.pid, signal.SIGKILL)
            p.wait(10)
        if p.stderr:
            p.stderr.close()

    def reload(self, extra: tuple[str, ...] | None = None) -> None:
        """Read the configuration (and its ACL file) again (SIGHUP), with the
        lines ``extra`` in place of those given at construction if given."""
        assert self.proc is not None
        if extra is not None:
            lines = self.conf.read_text().splitlines()
            lines = lines[:len(lines) - len(self.extra)] + list(extra)
            self.conf.write_text("\n".join(lines) + "\n")
            self.extra = tuple(extra)
        os.kill(self.proc.pid, signal.SIGHUP)

    def pause(self) -> None:
        """Stall it (SIGSTOP): connections stay open, nothing is answered."""
        assert self.proc is not None
        os.kill(self.proc.pid, signal.SIGSTOP)

    def resume(self) -> None:
        """Let a stalled broker go on (SIGCONT)."""
        assert self.proc is not None
        os.kill(self.proc.pid, signal.SIGCONT)

    def __enter__(self) -> Mosquitto:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
