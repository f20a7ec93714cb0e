"""What the RTU and TCP servers share: one background thread, stop, unplug.

A server owns one thread that serves its bus until :meth:`SimServer.stop`. Every
change of the port (unplug, replug) is made by that thread: other threads ask
for it and wait until it is done, so when :meth:`SimServer.unplug` returns the
port is gone.
"""

from __future__ import annotations

import abc
import contextlib
import logging
import math
import os
import select
import threading
import time
from collections.abc import Sequence

from pymb.sim.bus import Bus

__all__ = ["SimServer", "readable", "write_all"]

log = logging.getLogger("pymb.sim")

_REPLUG_RETRY_S = 1.0  # a real port that cannot be reopened is tried again this often


def readable(fds: Sequence[int], seconds: float | None) -> list[int]:
    """Those of ``fds`` with input (or a hang-up) within ``seconds`` (None:
    for ever), waited for with poll: any descriptor number."""
    p = select.poll()  # not select(): that one fails above descriptor 1023
    for fd in fds:
        p.register(fd, select.POLLIN)
    return [fd for fd, _ in p.poll(None if seconds is None
                                   else max(0, math.ceil(seconds * 1000)))]


def write_all(fd: int, data: bytes, wait_s: float) -> bool:
    """Write all of ``data`` to the non-blocking ``fd`` (a pseudo-terminal,
    a socket), waiting at most ``wait_s`` seconds for room; False when it
    cannot (nobody reads the other end, or it is gone)."""
    view = memoryview(data)
    deadline = time.perf_counter() + wait_s
    while view:
        try:
            view = view[os.write(fd, view):]
        except BlockingIOError:
            left = deadline - time.perf_counter()
            if left <= 0:
                return False
            p = select.poll()
            p.register(fd, select.POLLOUT)
            p.poll(max(1, math.ceil(left * 1000)))
        except OSError:
            return False
    return True


class SimServer(abc.ABC):
    """Base of :class:`~pymb.sim.rtu.RtuServer` and :class:`~pymb.sim.tcp.TcpServer`.

    Subclasses provide ``_open()`` (create the port), ``_close()`` (remove
    it) and ``_serve_once(wake_fd)`` (wait for input or ``wake_fd``, handle
    what came).
    """

    name = "server"

    def __init__(self, bus: Bus) -> None:
        self.bus = bus
        self._stop = threading.Event()
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        os.set_blocking(self._wake_w, False)
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        self._requests: list[tuple[str, float | None, threading.Event]] = []
        self._replug_at: float | None = None
        self._plugged = False
        self.unplugs = 0  #: times the port was unplugged

    # -- life cycle ----------------------------------------------------------------

    def start(self) -> None:
        """Open the port and start serving in a daemon thread."""
        self._open()
        self._plugged = True
        self._thread = threading.Thread(target=self._run, name=f"pymb-sim-{self.name}",
                                        daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop serving, close the port; safe to call twice."""
        self._stop.set()
        self._wake()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(5.0)
        self._thread = None
        if self._plugged:
            self._plugged = False
            self._close()
        for fd in (self._wake_r, self._wake_w):
            with contextlib.suppress(OSError):
                os.close(fd)
        self._wake_r = self._wake_w = -1

    @property
    def running(self) -> bool:
        """True while the serving thread runs."""
        return self._thread is not None and self._thread.is_alive()

    @property
    def plugged(self) -> bool:
        """False while the port is unplugged."""
        return self._plugged

    def unplug(self, seconds: float | None = None) -> None:
        """Remove the port (as a pulled USB adapter); back after ``seconds``
        or at :meth:`replug`."""
        self._control("unplug", seconds)

    def replug(self) -> None:
        """Bring the port back (a new pseudo-terminal: the link follows it)."""
        self._control("replug", None)

    # -- the thread ----------------------------------------------------------------

    def _control(self, what: str, seconds: float | None) -> None:
        if threading.current_thread() is self._thread or not self.running:
            self._apply(what, seconds)
            return
        done = threading.Event()
        with self._lock:
            self._requests.append((what, seconds, done))
        self._wake()
        if not done.wait(5.0):
            raise RuntimeError(f"the simulator did not {what} within 5 s")

    def _apply(self, what: str, seconds: float | None) -> None:
        if what == "unplug":
            if self._plugged:
                self._plugged = False
                self.unplugs += 1
                self._close()
                log.info("%s unplugged%s", self.name,
                         f" for {seconds:g} s" if seconds is not None else "")
            self._replug_at = None if seconds is None else time.perf_counter() + seconds
        elif not self._plugged:
            try:
                self._open()
            except OSError as e:
                log.warning("%s: cannot replug yet: %s", self.name, e)
                self._replug_at = time.perf_counter() + _REPLUG_RETRY_S
                return
            self._plugged = True
            self._replug_at = None
            log.info("%s replugged", self.name)

    def _wake(self) -> None:
        with contextlib.suppress(OSError):
            os.write(self._wake_w, b"!")

    def _drain_wake(self) -> None:
        try:
            while os.read(self._wake_r, 64):
                pass
        except OSError:
            pass

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                if self._requests:
                    with self._lock:
                        requests, self._requests = self._requests, []
                    for what, seconds, done in requests:
                        self._apply(what, seconds)
                        done.set()
                if self._plugged:
                    self._serve_once(self._wake_r)
                    continue
                timeout = None
                if self._replug_at is not None:
                    timeout = self._replug_at - time.perf_counter()
                    if timeout <= 0:
                        self._apply("replug", None)
                        continue
                readable([self._wake_r], timeout)
                self._drain_wake()
        except Exception:  # a bug must not leave a silent, half-dead simulator
            log.exception("%s stopped by an error", self.name)
            raise

    # -- for subclasses --------------------------------------------------------------

    @abc.abstractmethod
    def _open(self) -> None:
        """Create the port."""

    @abc.abstractmethod
    def _close(self) -> None:
        """Remove the port."""

    @abc.abstractmethod
    def _serve_once(self, wake_fd: int) -> None:
        """Wait for input or ``wake_fd``; handle what came."""
