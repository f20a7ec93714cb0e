"""What a logging run counts (:class:`Stats`), shared by its pollers, its
TCP loop and its writer."""

from __future__ import annotations

import threading
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

__all__ = ["Stats"]


@dataclass
class Stats:
    """Counts and problems of a run (thread-safe where pollers share them)."""

    samples: int = 0
    events: int = 0
    faults: int = 0
    skipped_slots: int = 0
    #: samples written, by device (the TCP loop's blocks: counted at each commit)
    by_device: Counter[str] = field(default_factory=Counter)
    #: what is wrong now, by bus or device name (empty: all is well)
    problems: dict[str, str] = field(default_factory=dict)
    opened: dict[str, bool] = field(default_factory=dict)  #: bus -> port opened at least once
    last_fault: dict[str, str] = field(default_factory=dict)  #: device or bus -> last fault
    device_faults: dict[str, int] = field(default_factory=dict)  #: map device -> failed polls
    #: map device -> the names of the points it refused (each point once, however often)
    unsupported: dict[str, set[str]] = field(default_factory=dict)
    lock: threading.Lock = field(default_factory=threading.Lock)
    #: the writer took its last items (:meth:`close`): skips are no longer counted
    closed: bool = False

    def fault(self, key: str, text: str) -> None:
        with self.lock:
            self.faults += 1
            self.problems[key] = text
            self.last_fault[key] = text

    def ok(self, key: str) -> None:
        if key in self.problems:
            with self.lock:
                self.problems.pop(key, None)

    def count(self, counts: dict[str, int], key: str, n: int) -> None:
        """Add ``n`` to ``counts[key]`` (one of the per-device counts)."""
        with self.lock:
            counts[key] = counts.get(key, 0) + n

    def refused(self, key: str, points: Iterable[str]) -> None:
        """The points device ``key`` refused in a reading (each counted once a run)."""
        with self.lock:
            self.unsupported.setdefault(key, set()).update(points)

    def skipped(self, n: int, say: Callable[[], None]) -> None:
        """Count ``n`` skipped slots and ``say`` so (add its event to what the
        poller hands over): both or neither, so that the summary's count is
        the stored events' sum. ``say`` runs under :attr:`lock`: it must not
        wait (on the writer's queue, which is bounded)."""
        with self.lock:
            if not self.closed:
                self.skipped_slots += n
                say()

    def close(self) -> None:
        """The writer takes its last items now: a poller left behind at the
        stop counts no skip whose event would not be stored."""
        with self.lock:
            self.closed = True

    @property
    def status(self) -> str:
        """``ok``, or the latest problem (and how many more there are)."""
        with self.lock:
            problems = list(self.problems.values())
        if not problems:
            return "ok"
        more = f" (+{len(problems) - 1} more)" if len(problems) > 1 else ""
        return problems[-1] + more
