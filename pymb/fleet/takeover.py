"""Two loggers with one node name (or two collectors with one client id):
:class:`Takeovers`.

The forwarder's MQTT client id is made of its profile and node name
(``pymb-plain-{node}``), so a second logger with the same node name connects
with the same client id, and the broker closes the first one's connection
(MQTT's session takeover: MQTT 5 brokers may say so, reason 0x8E; mosquitto
2.0 just closes the socket). Each reconnects and takes the session back,
endlessly. What shows it here: the broker ends a connection it had accepted,
within :data:`STABLE_S` seconds, :data:`IN_A_ROW` times in a row (or once
saying "session taken over"), with no connection refused or unanswered in
between (a restarted broker is away a moment; a takeover never is). It is
said once, in one line, and from the second such end in a row the
reconnection waits its doubling backoff (the forwarder's, up to 30 s) instead
of starting over, so two loggers take turns every few tens of seconds instead
of hundreds of times a minute.
"""

from __future__ import annotations

import time
from collections.abc import Callable

__all__ = ["IN_A_ROW", "STABLE_S", "TAKEN_OVER", "Takeovers"]

STABLE_S = 60.0  #: a connection ended sooner than this after its CONNACK is short-lived
IN_A_ROW = 3  #: short-lived connections ended by the broker, in a row, that are said
TAKEN_OVER = 0x8E  #: MQTT 5's DISCONNECT reason "Session taken over"


class Takeovers:
    """Counts the connections the broker ended soon after accepting them."""

    def __init__(self, client_id: str, node: str, longest: float,
                 clock: Callable[[], float] = time.monotonic, *,
                 second: str | None = None) -> None:
        self.client_id = client_id
        #: who the other client may be, for the line (a logger's: by its node name)
        self.second = second or f"a second logger with the node name {node!r}"
        self.longest = longest  #: the reconnection's longest backoff, in seconds
        self._clock = clock
        self._since: float | None = None
        self.short = 0  #: short-lived connections ended by the broker, in a row
        self.said = False  #: the line was said (until a connection lasts)

    def up(self) -> None:
        """A connection was accepted (its CONNACK)."""
        self._since = self._clock()

    def away(self) -> None:
        """A connection could not be made: the broker was away (stopped,
        restarting, out of reach), which a takeover never makes it; the
        short-lived connections before are no longer in a row."""
        self.short = 0

    def down(self, by_broker: bool, taken_over: bool) -> tuple[bool, str | None]:
        """The connection accepted last ended (``by_broker``: not by this side;
        ``taken_over``: the broker said so): whether the reconnection's backoff
        starts over, and the line to say (once) when it looks taken over."""
        lived = self._clock() - self._since if self._since is not None else 0.0
        self._since = None
        if not by_broker or lived >= STABLE_S:
            self.short = 0
            self.said = False
            return True, None
        self.short += 1
        line = None
        if not self.said and (taken_over or self.short >= IN_A_ROW):
            self.said = True
            why = ("the broker says another client took over this session" if taken_over else
                   f"the broker ended {self.short} connections in a row within "
                   f"{STABLE_S:g} s of accepting them")
            line = (f"{why}: is another client connected as {self.client_id} "
                    f"({self.second})? Two of them take the session from each other; "
                    f"reconnecting with a backoff up to {self.longest:g} s")
        return self.short < 2, line
