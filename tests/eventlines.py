"""The lines of a logger's stderr that are not its events: events are lines
there when stderr is not a terminal (``pymb.service.journal``), so a test
that counts what ``pymb log`` said looks past them."""

from __future__ import annotations

import re

__all__ = ["EVENT_LINE", "without_events"]

#: a logger's event as a line on stderr (pymb.service.journal.event_line):
#: ``pymb log: BUS[/DEVICE] KIND: message``
EVENT_LINE = re.compile(r"^pymb log: \S+ [a-z_]+: ")


def without_events(stderr: str) -> list[str]:
    """The lines of a logger's stderr that are not its events (which are lines there
    when stderr is not a terminal): what it said besides."""
    return [line for line in stderr.strip().splitlines() if not EVENT_LINE.match(line)]
