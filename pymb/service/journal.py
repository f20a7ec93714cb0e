"""Every event of a logging run as one line on stderr, when stderr is not a
terminal (a service: systemd's journal, or a file): timeouts, reconnects,
broker drops, clock steps show as they happen, not only in the database's
``events`` table.

Lines are rate-limited: at most :data:`BURST` of one kind from one bus or
device per :data:`WINDOW` seconds (a flood of one fault hides no other);
past that, one line says how many more went only to the events table.
"""

from __future__ import annotations

import sys
import time
from typing import TextIO

from pymb.store import Event, Sink, SinkWrapper

__all__ = ["BURST", "WINDOW", "EchoingSink", "EventLines", "echoing", "event_line"]

BURST = 10  #: lines at most per window, of one kind from one bus or device
WINDOW = 60.0  #: seconds


def event_line(e: Event) -> str:
    """``pymb log: line1/psu-a timeout: no reply ...`` (bus, device, kind, message)."""
    where = e.bus if e.device is None else f"{e.bus}/{e.device.name}"
    return f"pymb log: {where} {e.kind}: {e.message}"


class EventLines:
    """Writes events to ``out`` as lines, at most ``burst`` of a kind from a bus or
    device per ``window`` seconds."""

    def __init__(self, out: TextIO, *, burst: int = BURST, window: float = WINDOW) -> None:
        self.out: TextIO | None = out
        self.burst, self.window = burst, window
        self._window_start = -float("inf")
        self._shown: dict[tuple[str, str, str], int] = {}
        self._dropped = 0

    def __call__(self, e: Event) -> None:
        """Write one event (or count it, when the window is full)."""
        if self.out is None:
            return
        now = time.monotonic()
        lines = []
        if now - self._window_start >= self.window:
            if self._dropped:
                lines.append(f"pymb log: {self._dropped} more event(s) in the last "
                             f"{self.window:g} s are only in the events table")
            self._window_start, self._dropped = now, 0
            self._shown.clear()
        key = (e.bus, "" if e.device is None else e.device.name, e.kind)
        shown = self._shown.get(key, 0)
        if shown < self.burst:
            self._shown[key] = shown + 1
            lines.append(event_line(e))
        else:
            self._dropped += 1
        try:
            for line in lines:
                self.out.write(line + "\n")
            self.out.flush()
        except (OSError, ValueError):
            self.out = None  # nobody reads stderr: keep logging


def wanted(out: TextIO) -> bool:
    """True when events should go to ``out`` as lines: it is not a terminal."""
    try:
        return not out.isatty()
    except (OSError, ValueError):
        return False


class EchoingSink(SinkWrapper[Sink]):
    """A sink that writes every event it stores as a line too (see
    :class:`EventLines`); everything else goes to the sink it wraps."""

    def __init__(self, sink: Sink, out: TextIO | None = None) -> None:
        super().__init__(sink)
        self.lines = EventLines(sys.stderr if out is None else out)

    def event(self, event: Event) -> None:
        """Store the event, and write its line."""
        self.sink.event(event)
        self.lines(event)


def echoing(sink: Sink, out: TextIO | None = None) -> Sink:
    """``sink`` wrapped in an :class:`EchoingSink` when ``out`` (stderr by
    default) is not a terminal, else ``sink`` itself."""
    out = sys.stderr if out is None else out
    return EchoingSink(sink, out) if wanted(out) else sink
