"""CPU seconds of processes and of the whole machine over a span (Linux
``/proc``): who used the cores while a section ran, and whether they were all
busy (then a second process cannot run faster, whatever it is)."""

from __future__ import annotations

import os
import time
from collections.abc import Iterable
from dataclasses import dataclass

__all__ = ["Machine", "Span", "process_cpu", "status_field", "tree_cpu"]

_TICK = os.sysconf("SC_CLK_TCK")


def _stat(pid: int) -> list[str]:
    with open(f"/proc/{pid}/stat") as f:
        return f.read().rsplit(")", 1)[1].split()


def process_cpu(pid: int) -> float:
    """User + system CPU seconds of a process (all its threads) so far; 0 when
    it is gone."""
    try:
        f = _stat(pid)
    except OSError:
        return 0.0
    return (int(f[11]) + int(f[12])) / _TICK


def status_field(pid: int | str, key: str) -> int:
    """A number of ``/proc/PID/status`` (``VmRSS``: kB; ``Threads``); 0 when
    the line is missing. ``pid`` may be ``"self"``."""
    with open(f"/proc/{pid}/status", encoding="ascii") as f:
        return next((int(line.split()[1]) for line in f if line.startswith(key + ":")), 0)


def tree_cpu(pid: int) -> float:
    """CPU seconds of a process, of its children alive, and of the children it
    has waited for (a PostgreSQL server: the postmaster and its backends)."""
    try:
        f = _stat(pid)
    except OSError:
        return 0.0
    total = sum(int(x) for x in f[11:15]) / _TICK
    for entry in os.listdir("/proc"):
        if entry.isdigit() and entry != str(pid):
            try:
                c = _stat(int(entry))
            except OSError:
                continue
            if c[1] == str(pid):
                total += (int(c[11]) + int(c[12])) / _TICK
    return total


@dataclass
class Machine:
    """The machine's CPU time so far: busy (user, nice, system, interrupts)
    and all (busy, idle, I/O wait, stolen), in seconds summed over the cores."""

    busy: float
    total: float

    @classmethod
    def now(cls) -> Machine:
        """Read ``/proc/stat``."""
        with open("/proc/stat") as f:
            v = [int(x) for x in f.readline().split()[1:9]]
        user, nice, system, idle, iowait, irq, softirq, steal = v
        return cls((user + nice + system + irq + softirq) / _TICK,
                   (user + nice + system + idle + iowait + irq + softirq + steal) / _TICK)


class Span:
    """CPU seconds of named groups of processes, and the machine's busy cores,
    from :meth:`start` to :meth:`stop`."""

    def __init__(self, groups: dict[str, tuple[Iterable[int], bool]]) -> None:
        """``groups``: name -> (pids, whole tree)."""
        self.groups = {k: (list(p), tree) for k, (p, tree) in groups.items()}
        self.cpu: dict[str, float] = {}
        self.seconds = 0.0
        self.busy_cores = 0.0  #: cores busy on average, by anything on the machine
        self._t0 = 0.0
        self._m0 = Machine(0, 0)

    def _read(self) -> dict[str, float]:
        return {k: sum(tree_cpu(p) if tree else process_cpu(p) for p in pids)
                for k, (pids, tree) in self.groups.items()}

    def start(self) -> None:
        """Begin the span."""
        self.cpu = self._read()
        self._m0 = Machine.now()
        self._t0 = time.monotonic()

    def stop(self) -> None:
        """End it: ``cpu`` holds each group's CPU seconds over the span."""
        now = self._read()
        m = Machine.now()
        self.seconds = time.monotonic() - self._t0
        self.cpu = {k: now[k] - self.cpu[k] for k in now}
        self.busy_cores = ((m.busy - self._m0.busy) / self.seconds) if self.seconds > 0 else 0.0
