"""A bus thread hands a hub's sweeps to the writer as polls of a block (its
registers), unless it is to hand them decoded: logged ``--on-change`` (whose
rule compares the decoder's arrays, no value object each) or with its
channels' humidity in different units (the hub's own decode); a simulated
line."""

from __future__ import annotations

import queue
import threading
import time

import pytest

from pymb.devices.deviceconfig import DeviceConfig, parse_device
from pymb.devices.mapreading import MapReading
from pymb.logger.config import BusConfig
from pymb.logger.poller import BusPoller
from pymb.logger.stats import Stats
from pymb.sim import Simulator
from pymb.store import Event, Sample
from pymb.store.block import PollBlock

MIXED = DeviceConfig("hub", 250, options={"channels": 4, "humidity_unit": (0.1, 1, 0.1, 1)})


@pytest.mark.parametrize(("device", "decoded", "as_blocks"), [
    (parse_device("hub:250,channels=4"), False, True),
    (parse_device("hub:250,channels=4"), True, False),
    (MIXED, False, False),
])
def test_a_hubs_sweeps_go_as_registers_unless_they_are_to_go_decoded(
        device: DeviceConfig, decoded: bool, as_blocks: bool) -> None:
    with Simulator(["hub:250"], seed=3) as sim:
        bus = BusConfig("b", port=sim.port, interval=0.05, devices=[device])
        out: queue.Queue[list[Sample | Event | PollBlock]] = queue.Queue()
        stop = threading.Event()
        poller = BusPoller(bus, out, stop, Stats(), decoded=decoded)
        poller.start()
        polls: list[Sample | PollBlock] = []
        deadline = time.monotonic() + 30
        try:
            while len(polls) < 3 and time.monotonic() < deadline:
                polls += [i for i in out.get(timeout=30) if not isinstance(i, Event)]
        finally:
            stop.set()
            poller.join(10)
    assert len(polls) >= 3
    if as_blocks:
        assert all(isinstance(p, PollBlock) for p in polls)
        data = polls[0].samples()[0].data if isinstance(polls[0], PollBlock) else None
        assert isinstance(data, MapReading)
        assert data.blocks is None
    else:
        assert all(isinstance(p, Sample) for p in polls)
        sample = polls[0]
        assert isinstance(sample, Sample)
        assert isinstance(sample.data, MapReading)
        assert sample.data.blocks is not None  # (the decoder's arrays)
        humidity = sample.data.values["humidity_pct"]
        assert isinstance(humidity, list)
        assert len(humidity) == 4
