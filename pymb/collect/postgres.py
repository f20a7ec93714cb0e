"""Debian's PostgreSQL, run in a temporary folder on a free 127.0.0.1 port and
stopped by its PID: for the collector's tests and ``pymb bench --sections
collect`` (no system service, nothing installed).

PostgreSQL refuses to run as root: as root, the folder is given to the user
``postgres`` (which Debian's package makes), or ``nobody``, and ``initdb`` and
``postgres`` run as that user. The cluster trusts local connections of its
superuser ``pymb``; the database ``pymb`` is made at the first start.
"""

from __future__ import annotations

import contextlib
import glob
import os
import pwd
import shutil
import signal
import subprocess
import tempfile
import time
from pathlib import Path

from pymb.fleet.broker import free_port

__all__ = ["Postgres", "find_postgres"]

USER = "pymb"  #: the cluster's superuser
DATABASE = "pymb"


def find_postgres() -> Path | None:
    """The folder of Debian's ``initdb`` and ``postgres`` (the newest version)."""
    found = sorted(glob.glob("/usr/lib/postgresql/*/bin/postgres"),
                   key=lambda p: int(Path(p).parts[4]) if Path(p).parts[4].isdigit() else 0)
    if found:
        return Path(found[-1]).parent
    exe = shutil.which("postgres")
    return Path(exe).parent if exe else None


class Postgres:
    """One PostgreSQL cluster of its own. ``settings``: more ``-c NAME=VALUE``."""

    def __init__(self, *, port: int | None = None,
                 settings: dict[str, str] | None = None) -> None:
        bindir = find_postgres()
        if bindir is None:
            raise FileNotFoundError("PostgreSQL is not installed (apt-get install postgresql)")
        self.bindir = bindir
        self.port = port or free_port()
        self.settings = settings or {}
        self.dir = Path(tempfile.mkdtemp(prefix="pymb-pg-"))
        self.data = self.dir / "data"
        self.proc: subprocess.Popen[bytes] | None = None
        self._user: int | None = None
        self._group: int | None = None
        if os.geteuid() == 0:
            try:
                who = pwd.getpwnam("postgres")
            except KeyError:
                who = pwd.getpwnam("nobody")
            self._user, self._group = who.pw_uid, who.pw_gid
            os.chown(self.dir, who.pw_uid, who.pw_gid)
        self._run([str(bindir / "initdb"), "-D", str(self.data), "-U", USER, "--auth=trust",
                   "-E", "UTF8", "--no-sync", "--locale=C"])
        self._created = False

    def _run(self, argv: list[str]) -> None:
        p = subprocess.run(argv, capture_output=True, timeout=120, user=self._user,
                           group=self._group, extra_groups=[] if self._user is not None
                           else None, check=False, cwd=self.dir)
        if p.returncode:
            raise RuntimeError(f"{Path(argv[0]).name} failed: "
                               f"{(p.stderr or p.stdout).decode(errors='replace').strip()}")

    @property
    def url(self) -> str:
        """``postgresql://pymb@127.0.0.1:PORT/pymb``."""
        return f"postgresql://{USER}@127.0.0.1:{self.port}/{DATABASE}"

    @property
    def pid(self) -> int | None:
        """The postmaster's process id while it runs."""
        return None if self.proc is None else self.proc.pid

    def start(self, timeout: float = 60.0) -> None:
        """Start it, wait until it takes connections, make the database."""
        if self.proc is not None:
            raise RuntimeError("PostgreSQL is already running")
        argv = [str(self.bindir / "postgres"), "-D", str(self.data), "-p", str(self.port),
                "-c", "listen_addresses=127.0.0.1", "-c", f"unix_socket_directories={self.dir}"]
        for k, v in self.settings.items():
            argv += ["-c", f"{k}={v}"]
        log = open(self.dir / "postgres.log", "ab")  # noqa: SIM115 (the child keeps it)
        try:
            self.proc = subprocess.Popen(
                argv, stdin=subprocess.DEVNULL, stdout=log, stderr=log, cwd=self.dir,
                user=self._user, group=self._group,
                extra_groups=[] if self._user is not None else None)
        finally:
            log.close()
        deadline = time.monotonic() + timeout
        while not self._ready():
            if self.proc.poll() is not None:
                self.proc = None
                raise RuntimeError(f"postgres exited at start: {self.log()[-2000:]}")
            if time.monotonic() > deadline:
                self.stop()
                raise RuntimeError(f"postgres did not take connections on port {self.port}")
            time.sleep(0.1)

    def _ready(self) -> bool:
        import psycopg
        try:
            with psycopg.connect(f"postgresql://{USER}@127.0.0.1:{self.port}/postgres",
                                 connect_timeout=5, autocommit=True) as con:
                if not self._created:
                    if not con.execute("SELECT 1 FROM pg_database WHERE datname = %s",
                                       (DATABASE,)).fetchone():
                        con.execute(f"CREATE DATABASE {DATABASE}")
                    self._created = True
            return True
        except psycopg.OperationalError:
            return False

    def log(self) -> str:
        """What the server wrote to its log."""
        p = self.dir / "postgres.log"
        return p.read_text(errors="replace") if p.exists() else ""

    def stop(self) -> None:
        """Stop it by its PID: SIGINT (fast shutdown), SIGQUIT after 30 s."""
        p, self.proc = self.proc, None
        if p is None:
            return
        with contextlib.suppress(ProcessLookupError):
            os.kill(p.pid, signal.SIGINT)
        try:
            p.wait(30)
        except subprocess.TimeoutExpired:
            os.kill(p.pid, signal.SIGQUIT)
            p.wait(30)

    def cleanup(self) -> None:
        """Stop it and remove its folder."""
        self.stop()
        shutil.rmtree(self.dir, ignore_errors=True)

    def __enter__(self) -> Postgres:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.cleanup()
