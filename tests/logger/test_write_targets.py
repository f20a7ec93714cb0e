"""Write commands reach every logged device by its map, the CoolPro and the
hub too (no table of types): a bus thread's targets, against a simulated
line, and a write to the CoolPro's configuration through the poller's own
device, read back from the simulator."""

from __future__ import annotations

import queue
import threading
import time

from pymb.devices.deviceconfig import parse_device
from pymb.devices.mapwrite import WriteBudget
from pymb.logger.config import BusConfig
from pymb.logger.poller import BusPoller
from pymb.logger.stats import Stats
from pymb.logger.targets import write_targets
from pymb.sim import Simulator
from pymb.store import Event, Sample
from pymb.store.block import PollBlock


def test_the_coolpro_and_the_hub_are_write_targets_as_any_map_device() -> None:
    with Simulator(["coolpro", "hub:250"], seed=2) as sim:
        bus = BusConfig("b", port=sim.port, interval=0.2,
                        devices=[parse_device("coolpro"), parse_device("hub:250,channels=5")])
        out: queue.Queue[list[Sample | Event | PollBlock]] = queue.Queue()
        stop = threading.Event()
        poller = BusPoller(bus, out, stop, Stats())
        poller.start()
        try:
            targets = write_targets([poller], WriteBudget())
            assert sorted(targets) == ["coolpro-40", "hub-250"]
            assert targets["coolpro-40"].map.id == "coolpro"
            deadline = time.monotonic() + 30
            while targets["coolpro-40"].device() is None and time.monotonic() < deadline:
                time.sleep(0.05)
            dev = targets["coolpro-40"].device()
            assert dev is not None
            assert not targets["coolpro-40"].offline()
            dev.write("baud_rate_index", 2)
            assert dev.read("baud_rate_index") == {"baud_rate_index": 2}
            assert not [p for p in targets["hub-250"].map.points.values() if p.writable]
        finally:
            stop.set()
            poller.join(10)
    assert not poller.is_alive()
