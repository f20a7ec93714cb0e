"""Child processes of the bench: simulators and contender workers.

They are :class:`pymb.child.Child` processes (the one launcher: own session,
``PR_SET_PDEATHSIG``, stderr kept in a file and shown when one fails, a
deadline on every exchange). :class:`Children` stops them all, newest first,
on the way out of a ``with`` block: normal end, error or Ctrl-C.
"""

from __future__ import annotations

import contextlib
from collections.abc import Sequence
from types import TracebackType

from pymb.child import ROOT, Child, ChildError, pymb_argv, python_env

__all__ = ["ROOT", "Child", "ChildError", "Children", "SimChild", "python_env"]


class SimChild(Child):
    """``python -m pymb simulate ARGS`` (what :class:`pymb.sim.SimulatorProcess`
    runs), with its stderr kept out of the table; :attr:`port` is the
    pseudo-terminal it printed."""

    def __init__(self, args: Sequence[str]) -> None:
        super().__init__("simulator " + " ".join(args), pymb_argv("simulate", *args),
                         stdin=False)
        self.args = list(args)
        self.port = ""

    def wait_ready(self, timeout: float = 20.0) -> SimChild:
        """Wait for the endpoint line."""
        self.port = self.readline(timeout).strip()
        if not self.port.startswith("/"):
            raise ChildError(f"{self.name}: printed {self.port!r}, not a port")
        return self

    def stop(self, *, grace: float = 1.0, term_wait: float = 5.0) -> int | None:
        """SIGTERM (the simulator's clean stop), then SIGKILL."""
        return super().stop(grace=grace, term_wait=term_wait)


class Children:
    """Owns children; stops every one on exit, newest first."""

    def __init__(self) -> None:
        self._children: list[Child] = []

    def add(self, child: Child) -> Child:
        """Take ``child`` into care."""
        self._children.append(child)
        return child

    def sims(self, args_list: Sequence[Sequence[str]], timeout: float = 30.0) -> list[SimChild]:
        """Start simulators side by side and wait until each serves."""
        sims = [SimChild(a) for a in args_list]
        self._children.extend(sims)
        for s in sims:
            s.wait_ready(timeout)
        return sims

    def stop(self, child: Child) -> None:
        """Stop one child now."""
        child.stop()
        with contextlib.suppress(ValueError):
            self._children.remove(child)

    def stop_all(self) -> None:
        """Stop every child, newest first."""
        while self._children:
            child = self._children.pop()
            with contextlib.suppress(Exception):
                child.stop()

    def __enter__(self) -> Children:
        return self

    def __exit__(self, et: type[BaseException] | None, ev: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.stop_all()
