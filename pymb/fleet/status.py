"""What the forwarder says of itself: a snapshot for the status line and the
summary of ``pymb log --mqtt`` and ``pymb forward``."""

from __future__ import annotations

import time
from dataclasses import dataclass

__all__ = ["ForwarderStatus"]


@dataclass(frozen=True)
class ForwarderStatus:
    """A snapshot of the forwarder, for the status line and the summary."""

    connected: bool
    state: str  #: connected, connecting, a reason for the disconnection
    published: int  #: samples published (repeats included)
    acked: int  #: samples acknowledged by the broker
    backlog: int  #: samples committed and not yet acknowledged
    backlog_age: float | None  #: seconds since the oldest of them was taken
    last_ack: float | None  #: time.time() of the last acknowledgement
    rate: float  #: samples acknowledged per second, over the last few seconds
    connections: int  #: successful connections so far
    cursor: int  #: every sample id up to this one was acknowledged (the outbox cursor)
    #: the broker's reason while it refuses samples (MQTT 5); they are kept and offered again
    refusal: str | None = None

    def line(self) -> str:
        """A short status: ``mqtt ok 152/s backlog 0``; ``mqtt refused (Not
        authorized) ...`` while the broker refuses samples."""
        head = "mqtt " + ("ok" if self.connected else self.state)
        if self.refusal is not None:
            head = f"mqtt refused ({self.refusal})"
        # the age of a backlog, not of the few samples in flight a moment
        age = "" if self.backlog_age is None or not self.backlog or self.backlog_age < 1 \
            else f" ({self.backlog_age:.0f} s old)"
        ack = "-" if self.last_ack is None else time.strftime(
            "%H:%M:%S", time.localtime(self.last_ack))
        return f"{head} {self.rate:,.0f}/s backlog {self.backlog:,}{age} last ack {ack}"
