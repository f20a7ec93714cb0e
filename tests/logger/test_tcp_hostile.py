"""The one TCP loop (:mod:`pymb.logger.tcploop`) against hostile gateways
(:mod:`hostile_gateway`): whatever a gateway does, the loop keeps going,
stores only the registers of the right request of the right unit, counts
the fault against the device, records it as an event and recovers."""

from __future__ import annotations

from pathlib import Path

from hostile_gateway import Hostile, poll


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
