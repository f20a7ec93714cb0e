"""Child processes of the bench: simulators and contender workers.

They are :class:`pymb.child.Child` processes (the one launcher: own session,
``PR_SET_PDEATHSIG``, stderr kept in a file and shown when one fails, a
deadline on every exchange). :class:`Children` stops them all, newest first,
on the way out of a ``with`` block: normal end, error or Ctrl-C.
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Sequence
from types import TracebackType
from typing import IO, Any

from pymb.bench.forked import fork_module, fork_safe, preload
from pymb.child import ROOT, Child, ChildError, Process, pymb_argv, python_env

__all__ = ["ROOT", "Child", "ChildError", "Children", "ForkedChild", "SimChild", "python_env"]


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


class ForkedChild(Child):
    """A :class:`Child` forked from this process when its argv is a pymb
    module it may fork now (:func:`pymb.bench.forked.fork_safe`; ``--quick``),
    started as usual otherwise."""

    def _launch(self, stdin: bool, err: IO[bytes] | int | None, env: dict[str, str],
                cwd: str | None) -> Process:
        if fork_safe(self.argv):
            return fork_module(self.argv, stdin=stdin, err=err, env=env, cwd=cwd)
        return super()._launch(stdin, err, env, cwd)


class _ForkedSim(ForkedChild, SimChild):
    """A :class:`SimChild` forked from this process (``--quick``)."""


class Children:
    """Owns children; stops every one on exit, newest first. With ``fork``
    (``--quick``), pymb's own children are forked from this process rather
    than started as new interpreters (:mod:`pymb.bench.forked`)."""

    def __init__(self, *, fork: bool = False) -> None:
        self._children: list[Child] = []
        self.fork = fork
        if fork:
            preload()
        self._lock = threading.Lock()  # the SD wear runs start theirs from a thread

    def add(self, child: Child) -> Child:
        """Take ``child`` into care."""
        with self._lock:
            self._children.append(child)
        return child

    def start(self, name: str, argv: Sequence[str], **kw: Any) -> Child:
        """Start a child (forked with ``fork``, see above) and take it into care."""
        return self.add((ForkedChild if self.fork else Child)(name, argv, **kw))

    def sims(self, args_list: Sequence[Sequence[str]], timeout: float = 30.0) -> list[SimChild]:
        """Start simulators side by side and wait until each serves."""
        sims = [(_ForkedSim if self.fork else SimChild)(a) for a in args_list]
        with self._lock:
            self._children.extend(sims)
        for s in sims:
            s.wait_ready(timeout)
        return sims

    def stop(self, child: Child) -> None:
        """Stop one child now."""
        child.stop()
        with self._lock, contextlib.suppress(ValueError):
            self._children.remove(child)

    def stop_all(self) -> None:
        """Stop every child, newest first."""
        while True:
            with self._lock:
                if not self._children:
                    return
                child = self._children.pop()
            with contextlib.suppress(Exception):
                child.stop()

    def __enter__(self) -> Children:
        return self

    def __exit__(self, et: type[BaseException] | None, ev: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.stop_all()
