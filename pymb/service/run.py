"""What ``pymb log`` does as a service, around a :class:`pymb.logger.Logger`:
``READY=1``, ``WATCHDOG=1`` and ``STATUS=`` from the writer loop
(:mod:`pymb.service.notify`), and SIGHUP as a reload when there is no
controlling terminal (:mod:`pymb.service.reload`)."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Generic, Protocol, TypeVar

from pymb.service.notify import Notifier
from pymb.service.reload import Reload, controlling_terminal, exec_again
from pymb.store import Event, Sink

__all__ = ["Logged", "Service"]


class Logged(Protocol):
    """What a service needs of the logger it runs
    (:class:`pymb.logger.Logger`, which sits above this package)."""

    on_hangup: Callable[[], None] | None

    @property
    def sink(self) -> Sink:
        """Where it writes."""
        ...

    def stop(self) -> None:
        """Ask the run to end."""
        ...


L = TypeVar("L", bound=Logged)


class Service(Generic[L]):
    """``tick(inner)`` is the logger's ``tick`` (``inner``, the status line, is
    called as before); :meth:`attach` takes the logger's SIGHUP; after the run,
    :meth:`finish` (which executes pymb again when the run stopped for a reload).

    ``check_config`` reads the configuration again (raising InvalidArgument for a
    mistake); ``text(logger, elapsed)`` is the status, for ``STATUS=``."""

    def __init__(self, check_config: Callable[[], object],
                 text: Callable[[L, float], str]) -> None:
        self.notifier = Notifier()
        self.reload: Reload | None = None if controlling_terminal() else Reload(check_config)
        self.text = text
        self.logger: L | None = None

    def attach(self, logger: L) -> None:
        """Take ``logger``'s SIGHUP (a reload, without a controlling terminal)."""
        self.logger = logger
        if self.reload is not None:
            logger.on_hangup = self.reload.hangup

    def tick(self, inner: Callable[[L, float, bool], None] | None,
             ) -> Callable[[L, float, bool], None]:
        """The logger's tick: the service's turn, then ``inner``'s."""
        def tick(logger: L, elapsed: float, final: bool) -> None:
            if not final:
                self._turn(logger, elapsed)
            if inner is not None:
                inner(logger, elapsed, final)
        return tick

    def _event(self, logger: L, kind: str, message: str) -> None:
        logger.sink.event(Event(time.time(), time.monotonic(), "service", None, kind, None,
                                message))

    def _turn(self, logger: L, elapsed: float) -> None:
        n = self.notifier
        if n.enabled:
            if not n.ready_sent:
                n.ready(self.text(logger, elapsed))
            n.tick(self.text(logger, elapsed) if n.status_due() else None)
        r = self.reload
        if r is not None and r.pending:
            if r.due():
                n.reloading()
                self._event(logger, "reload", "SIGHUP: reloading the configuration; every "
                                              "sample read so far is committed first")
                logger.stop()
            else:
                self._event(logger, "reload", f"SIGHUP: the new configuration is refused "
                                              f"({r.refused}); the running one goes on")

    def finish(self) -> None:
        """After the run: execute pymb again for a reload, else ``STOPPING=1``."""
        if self.reload is not None and self.reload.requested:
            self.notifier.close()
            exec_again()
        self.notifier.stopping()
        self.notifier.close()
