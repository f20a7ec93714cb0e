"""SIGHUP: reload the configuration, when pymb runs as a service.

A process with a controlling terminal (someone's shell or ssh session) gets
SIGHUP when that terminal hangs up: ``pymb log`` then stops, as SIGTERM
stops it. A process without one (a systemd service, anything started with
``setsid``) takes SIGHUP as "reload": the new configuration is checked
first (a mistake is an event and a line on stderr, and the running
configuration goes on); then the run stops as at SIGTERM, committing every
sample it read, and pymb executes itself again with the same arguments and
the same process id, reading the configuration afresh. ``systemctl reload
pymb`` sends the signal (``ExecReload=`` in ``contrib/pymb.service``).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable

from pymb.errors import InvalidArgument

__all__ = ["Reload", "controlling_terminal", "exec_again"]


def controlling_terminal() -> bool:
    """True when this process has a controlling terminal."""
    try:
        fd = os.open("/dev/tty", os.O_RDONLY | os.O_NOCTTY)
    except OSError:
        return False
    os.close(fd)
    return True


class Reload:
    """A SIGHUP's request to reload: :meth:`hangup` (from the signal handler)
    marks it; :meth:`due` (from the main loop) checks the new configuration
    with ``check`` and says whether to stop for the reload."""

    def __init__(self, check: Callable[[], object]) -> None:
        self.check = check
        self.pending = False
        self.requested = False  #: the run stopped for a reload: exec_again() next
        self.refused: str | None = None  #: why the last request was refused

    def hangup(self) -> None:
        """The signal came (signal-safe: only sets a flag)."""
        self.pending = True

    def due(self) -> bool:
        """True (once) when a reload was asked for and the new configuration
        is good; a bad one sets :attr:`refused` and returns False."""
        if not self.pending:
            return False
        self.pending = False
        try:
            self.check()
        except InvalidArgument as e:
            self.refused = str(e)
            return False
        self.refused = None
        self.requested = True
        return True


def exec_again() -> None:
    """Replace this process by a new ``pymb`` with the same command line."""
    sys.stdout.flush()
    sys.stderr.flush()
    os.execv(sys.executable, [sys.executable, *sys.orig_argv[1:]])
