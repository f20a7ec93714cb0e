"""systemd's notify protocol (``sd_notify(3)``), without libsystemd.

A service of ``Type=notify`` finds the path of a datagram socket in
``$NOTIFY_SOCKET`` (a file system path, or ``@name`` for Linux's abstract
namespace) and sends it newline-separated ``KEY=VALUE`` assignments:
``READY=1`` once it works, ``STATUS=...`` (shown by ``systemctl status``),
``WATCHDOG=1`` at least every ``$WATCHDOG_USEC`` microseconds when the unit
sets ``WatchdogSec=`` (``$WATCHDOG_PID``, when set, names the process
meant), ``RELOADING=1`` and ``STOPPING=1``. Without ``$NOTIFY_SOCKET``
every call does nothing; a send that fails is ignored, as sd_notify's
callers do.
"""

from __future__ import annotations

import contextlib
import os
import socket
import time
from collections.abc import Mapping

__all__ = ["Notifier"]

#: seconds between two STATUS= updates, at most one per this
STATUS_EVERY = 5.0


class Notifier:
    """The service manager's end of the notify protocol, for one process.

    ``env`` is the environment to read (``os.environ`` by default)."""

    def __init__(self, env: Mapping[str, str] | None = None) -> None:
        env = os.environ if env is None else env
        self.address: str | bytes | None = None
        path = env.get("NOTIFY_SOCKET", "")
        if path.startswith("@"):  # the abstract namespace: a leading NUL byte
            self.address = b"\0" + path[1:].encode()
        elif path.startswith("/"):
            self.address = path
        usec = env.get("WATCHDOG_USEC", "")
        pid = env.get("WATCHDOG_PID", "")
        #: seconds between WATCHDOG=1 pings (half the manager's timeout), None: no watchdog
        self.watchdog_every: float | None = None
        if usec.isdigit() and int(usec) > 0 and (not pid or pid == str(os.getpid())):
            self.watchdog_every = int(usec) / 2e6
        self._sock: socket.socket | None = None
        self._last_ping = self._last_status = -float("inf")
        self.ready_sent = False

    @property
    def enabled(self) -> bool:
        """True when a service manager listens."""
        return self.address is not None

    def send(self, *assignments: str) -> bool:
        """Send ``KEY=VALUE`` lines in one datagram; False if it did not go."""
        if self.address is None:
            return False
        message = "\n".join(assignments).encode("utf-8", "replace")
        try:
            if self._sock is None:
                self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
            self._sock.sendto(message, self.address)
        except OSError:
            return False
        return True

    def ready(self, status: str = "") -> None:
        """``READY=1`` (and a first status)."""
        self.ready_sent = True
        self.send("READY=1", *([f"STATUS={status}"] if status else []))
        self._last_ping = self._last_status = time.monotonic()

    def tick(self, status: str | None = None) -> None:
        """From the service's main loop: ``WATCHDOG=1`` when one is due, and
        ``status`` (when given) at most every :data:`STATUS_EVERY` seconds."""
        if self.address is None:
            return
        now = time.monotonic()
        lines = []
        if self.watchdog_every is not None and now - self._last_ping >= self.watchdog_every:
            lines.append("WATCHDOG=1")
            self._last_ping = now
        if status is not None and now - self._last_status >= STATUS_EVERY:
            lines.append(f"STATUS={status}")
            self._last_status = now
        if lines:
            self.send(*lines)

    def status_due(self) -> bool:
        """True when :meth:`tick` would send a status now (so the caller
        builds the text only then)."""
        return self.address is not None and \
            time.monotonic() - self._last_status >= STATUS_EVERY

    def reloading(self) -> None:
        """``RELOADING=1``: the service reloads its configuration; the next
        ``READY=1`` ends the reload (``MONOTONIC_USEC`` as systemd 253 wants)."""
        usec = time.clock_gettime_ns(time.CLOCK_MONOTONIC) // 1000
        self.send("RELOADING=1", f"MONOTONIC_USEC={usec}")

    def stopping(self, status: str = "") -> None:
        """``STOPPING=1``: the service is shutting down."""
        self.send("STOPPING=1", *([f"STATUS={status}"] if status else []))

    def close(self) -> None:
        """Release the socket."""
        if self._sock is not None:
            with contextlib.suppress(OSError):
                self._sock.close()
            self._sock = None
