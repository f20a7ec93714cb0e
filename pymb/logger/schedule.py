"""The one schedule of ``pymb log``, as its pollers take it: a bus's thread
(:mod:`pymb.logger.poller`) and the one TCP loop (:mod:`pymb.logger.tcploop`)
both run it and do only the reading and the writing.

- The rules, from :mod:`pymb.devices.polls` (below the logger: ``pymb
  watch`` and the bench's bare loop keep them too): :class:`Slot` (drift-free
  slots, the skipped ones counted; flat out; ``once`` groups, read again
  when the device :func:`reappeared`), :class:`Agenda` (which slots are due
  when), :class:`Health` (a device offline for ``offline_retry`` after
  ``offline_after`` failed polls, or, for a map of ``backoff = true``, backed
  off 0.5 s doubling to 30 s) and :class:`Backoff` (a bus that does not open,
  tried again 0.5 s doubling to 30 s later).
- The batching of samples for the writer (:data:`BATCH_MAX`, :data:`BATCH_AGE`)
  and the text of each event the pollers record (:data:`TEXT`).
"""

from __future__ import annotations

from pymb.devices.polls import (
    BACKOFF,
    BACKOFF_FIRST,
    BACKOFF_MAX,
    OFFLINE,
    SKIPPED,
    Agenda,
    Backoff,
    Health,
    Slot,
    reappeared,
)

__all__ = ["BACKOFF_FIRST", "BACKOFF_MAX", "BATCH_AGE", "BATCH_MAX", "TEXT", "Agenda", "Backoff",
           "Health", "Slot", "reappeared"]

#: A poller hands its samples to the writer in lists of at most this many, or
#: this old (seconds), and before it waits: one queue operation per list, not
#: two per sample. Events go at once, after the samples before them.
BATCH_MAX = 64
BATCH_AGE = 0.02

#: The text of each event the pollers record, one per fact (``str.format``
#: fields); a failed poll's text is its error's, with "offline" or "backoff".
TEXT = {
    "connect": "polling {devices} device(s) on {endpoint}",
    "reconnect": "reconnected to {endpoint}",
    "retrying": "{why}; retrying in {wait:g} s",
    "lost": "{endpoint}: {why}{retry}",
    "closed": "{endpoint}: the connection was closed by the device after {replies}; "
              "opening it again",
    "closes": "{endpoint} closes the connection after {replies}: {n} request(s) per "
              "connection from now on",
    "stray": "{endpoint}: bytes no request asked for (received {got})",
    "no_value": "{name} supplied no value: {why}",
    "skipped": SKIPPED,
    "online": "{name} answers again",
    "offline": OFFLINE,
    "backoff": BACKOFF,
}
