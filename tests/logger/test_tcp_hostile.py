"""The one TCP loop (:mod:`pymb.logger.tcploop`) against hostile gateways
(:mod:`hostile_gateway`): whatever a gateway does, the loop keeps going,
stores only the registers of the right request of the right unit, counts
the fault against the device, records it as an event and recovers."""

from __future__ import annotations

import socket
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from hostile_gateway import Handed, Hostile, Request, Script, good, poll


def test_a_gateway_that_drops_every_connection_is_retried_with_the_backoff(
        tmp_path: Path) -> None:
    """Accepted, then closed at once, every time: the bus is opened again
    after 0.5 s, then 1 s (as a refused connection is), not at once in a
    loop that fills the log with events."""
    gw = Hostile(None)
    try:
        got = poll(tmp_path, [gw.port], lambda h: h.kinds().count("connection") >= 3)
    finally:
        gw.close()
    assert len(gw.accepted) >= 3
    assert gw.accepted[2] - gw.accepted[0] >= 1.4, gw.accepted
    assert got.samples == []
    # an event per connection lost, each told to the device it was polling
    lost = [e for e in got.events if e.kind == "connection"]
    assert len(lost) == len(gw.accepted) == 3
    assert all(e.device is not None and e.device.address == 1 for e in lost), lost
    assert got.stats.device_faults["hx-1"] == len(lost)


def _once(lie: Callable[[bytes], bytes], at: int = 3) -> Script:
    """A script answering right but for the ``at``-th request of all,
    whose reply is ``lie(right reply)``."""
    seen = [0]

    def script(n: int, req: Request, conn: socket.socket) -> bytes:
        seen[0] += 1
        reply = good(*req)
        return lie(reply) if seen[0] == at else reply
    return script


def test_a_reply_whose_length_lies_costs_one_timeout(tmp_path: Path) -> None:
    """A reply whose length field promises more than comes: one timeout,
    then a new connection (the bytes left over would be read as the start
    of the next replies, which would time out one after the other)."""
    gw = Hostile(_once(lambda r: r[:4] + b"\x00\x40" + r[6:]))
    try:
        got = poll(tmp_path, [gw.port], lambda h: len(h.samples) >= 12)
    finally:
        gw.close()
    assert got.kinds().count("timeout") == 1, got.events
    assert "reconnect" in got.kinds()
    assert len(got.samples) >= 12
    assert got.values() == {(1, (100, 101))}


def test_a_name_lookup_that_hangs_does_not_stop_the_other_buses(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The resolver takes its time over one bus's host name (a board whose
    DNS server is gone waits seconds per lookup): the other buses are polled
    meanwhile, and the name that does not resolve is one event line."""
    release = threading.Event()
    blocked = threading.Event()
    real = socket.getaddrinfo

    def slow(host: Any, *args: Any, **kwargs: Any) -> Any:
        if host == "slow.invalid":
            blocked.set()
            release.wait(10.0)
            raise socket.gaierror(socket.EAI_NONAME, "Name or service not known")
        return real(host, *args, **kwargs)

    monkeypatch.setattr(socket, "getaddrinfo", slow)
    gw = Hostile(lambda n, req, conn: good(*req))
    meanwhile: list[int] = []

    def until(h: Handed) -> bool:
        if not release.is_set() and blocked.is_set() and len(h.samples) >= 10:
            meanwhile.append(len(h.samples))  # read while the lookup hung
            release.set()
        return release.is_set() and "connection" in h.kinds()

    try:
        got = poll(tmp_path, ["slow.invalid:502", gw.port], until)
    finally:
        release.set()
        gw.close()
    assert meanwhile, "no samples while a lookup hung"
    lost = [e for e in got.events if e.kind == "connection"]
    assert lost[0].bus == "bus1"
    assert lost[0].message.startswith("the host name 'slow.invalid' did not resolve"), lost
    assert "\n" not in lost[0].message
    assert got.values() == {(1, (100, 101))}
