"""A user's simulated device needs only ``handle``: ``sensor_fault`` has a
default (nothing to fault), as before the hooks became abstract."""

from __future__ import annotations

import random

from pymb.sim import Device


class Echo(Device):
    kind = "echo"

    def handle(self, pdu: bytes) -> bytes | None:
        return pdu


def test_a_device_with_only_handle_is_made_and_answers() -> None:
    dev = Echo(5, baud=9600, seed=0, clock=None)
    assert dev.handle(b"\x03\x00\x00\x00\x01") == b"\x03\x00\x00\x00\x01"
    assert dev.sensor_fault(random.Random(0), 1.0) == "no sensors to fault"
