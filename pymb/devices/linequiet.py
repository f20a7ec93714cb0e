"""The silences a line keeps between requests: one :class:`Quiet` per
client, shared by the map devices on it (:mod:`pymb.devices.mapdevice`)."""

from __future__ import annotations

import threading
import time
import weakref

from pymb.client import Client
from pymb.client.core import line_lock

__all__ = ["Quiet", "quiet_of", "sleep_until"]


class Quiet:
    """When the line of one client may carry the next request: a device's
    ``turnaround`` keeps it silent after its reply for every device on it."""

    __slots__ = ("gapped", "last_end", "lock", "quiet_until")

    def __init__(self, lock: threading.RLock) -> None:
        #: when the last request on the line ended: kept once a device on it
        #: keeps a gap after the last request (:attr:`gapped`), and by the
        #: devices that keep a turnaround
        self.last_end = 0.0
        self.quiet_until = 0.0
        #: some device on the line keeps an ``inter_request_gap``
        self.gapped = False
        #: the line's lock, the client's own (reentrant, each request takes
        #: it): a map device holds it for each whole read or write (from the
        #: wait for silence to the end of its last request, and its decoding),
        #: so two map devices on one client in two threads, or a map device
        #: and the client's own requests, keep each other's silences
        self.lock = lock


# One per client, shared by the devices on it; gone with the client.
_LINES: weakref.WeakKeyDictionary[Client, Quiet] = weakref.WeakKeyDictionary()
_LINES_LOCK = threading.Lock()


def quiet_of(client: Client) -> Quiet:
    """The :class:`Quiet` of ``client``'s line, made on first use."""
    with _LINES_LOCK:
        q = _LINES.get(client)
        if q is None:
            q = _LINES[client] = Quiet(line_lock(client))
        return q


def sleep_until(t: float) -> None:
    """Sleep until ``time.monotonic()`` reaches ``t``."""
    while True:
        left = t - time.monotonic()
        if left <= 0:
            return
        time.sleep(left)
