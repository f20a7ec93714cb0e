"""The schedule on a bus's own thread (a serial line), end to end: a
simulated SDM120 on a pseudo-terminal, ``pymb log``'s Logger writing a real
SQLite file. Its "once" group (``config``, interval 0) is read once each time
the device appears: at the start and again after the port was pulled and
came back, never on every poll; its ``fast`` group goes on at its interval.
A device that goes offline is not asked for its other groups in that round."""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

from conftest import wait_until
from dbwait import count, wait_for

from pymb import maps
from pymb.logger import Logger, load_config
from pymb.sim import Simulator
from pymb.sim.mapsim import MapSimDevice

_GROUP = ("SELECT COUNT(*) FROM samples s JOIN devices d ON d.id = s.device_id "
          "WHERE d.humidity_units = ?")


def test_a_once_group_is_read_again_when_the_device_reappears(tmp_path: Path) -> None:
    db = tmp_path / "once.sqlite"
    with Simulator([MapSimDevice(maps.builtin("eastron-sdm120"), 3)], seed=3) as sim:
        conf = tmp_path / "log.toml"
        conf.write_text(f'''[output]
path = "{db}"
commit_interval_s = 0.2
[[bus]]
name = "line"
port = "{sim.port}"
timeout = 0.3
interval = 0.5
[[bus.device]]
type = "eastron-sdm120"
address = 3
''')
        logger = Logger(load_config(conf))
        result: list[Any] = []
        t = threading.Thread(target=lambda: result.append(logger.run(120)))  # stopped below
        t.start()
        try:
            wait_for(db, _GROUP, ("group=fast",), at_least=3, timeout=30)
            assert count(db, _GROUP, ("group=config",)) == 1  # once, not at each slot
            sim.unplug(0.5)
            wait_for(db, "SELECT COUNT(*) FROM events WHERE kind = 'reconnect'", timeout=30)
            wait_for(db, _GROUP, ("group=config",), at_least=2, timeout=30)
            fast = count(db, _GROUP, ("group=fast",))
            wait_for(db, _GROUP, ("group=fast",), at_least=fast + 3, timeout=30)
        finally:
            logger.stop()
            t.join(30)
    assert not t.is_alive()
    wait_until(lambda: bool(result), "the summary", 5)
    assert count(db, _GROUP, ("group=config",)) == 2
    assert count(db, _GROUP, ("group=energy",)) >= 1


def test_a_device_that_goes_offline_is_not_asked_again_in_the_same_round(
        tmp_path: Path) -> None:
    """An absent SDM120 (three groups due at the start, ``offline_after = 1``)
    costs the bus one timeout, not one per group; the live one beside it is
    read on."""
    db = tmp_path / "round.sqlite"
    with Simulator([MapSimDevice(maps.builtin("eastron-sdm120"), 3)], seed=3) as sim:
        conf = tmp_path / "log.toml"
        conf.write_text(f'''[output]
path = "{db}"
commit_interval_s = 0.2
[[bus]]
name = "line"
port = "{sim.port}"
timeout = 0.3
interval = 0.5
[[bus.device]]
type = "eastron-sdm120"
address = 3
[[bus.device]]
type = "eastron-sdm120"
address = 4
offline_after = 1
offline_retry = 600
''')
        logger = Logger(load_config(conf))
        result: list[Any] = []
        t = threading.Thread(target=lambda: result.append(logger.run(120)))  # stopped below
        t.start()
        try:
            wait_for(db, "SELECT COUNT(*) FROM events WHERE kind = 'timeout'", timeout=30)
            live = ("group=fast",)
            wait_for(db, _GROUP + " AND d.name = 'eastron-sdm120-3'", live, at_least=4,
                     timeout=30)
        finally:
            logger.stop()
            t.join(30)
    assert not t.is_alive()
    timeouts = count(db, "SELECT COUNT(*) FROM events WHERE kind = 'timeout'")
    assert timeouts == 1, timeouts
    assert count(db, _GROUP + " AND d.name = 'eastron-sdm120-4'", ("group=fast",)) == 0
