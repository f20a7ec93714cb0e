"""``--mqtt`` publishes from the writer's open batch: a sample reaches the
broker before its commit, and forwarding adds no commit of its own beyond
the id mark (pymb.store.ids) and its events; the ids stay under the mark."""

from __future__ import annotations

import sqlite3
import threading
from pathlib import Path

import pytest

pytest.register_assert_rewrite("mqtt_broker")
from mqtt_broker import Fleet, plain_ids  # noqa: E402

from pymb.fleet import ForwardingSink, MqttConfig  # noqa: E402
from pymb.fleet.forwarder import Forwarder  # noqa: E402
from pymb.logger import BusConfig, DeviceConfig, LogConfig, Logger  # noqa: E402
from pymb.store import SqliteSink  # noqa: E402
from pymb.store.ids import BLOCK, RESERVED_KEY  # noqa: E402

pytest_plugins = ["mqtt_broker"]


class _Counting(SqliteSink):
    """The SQLite sink, counting its commits."""

    commits = 0

    def _commit(self) -> None:
        super()._commit()
        self.commits += 1


def _committed(db: Path) -> set[int]:
    con = sqlite3.connect(db)
    try:
        return {int(i) for (i,) in con.execute("SELECT id FROM samples")}
    finally:
        con.close()


def test_samples_reach_the_broker_before_their_commit(fleet: Fleet, tmp_path: Path) -> None:
    broker = fleet.broker()
    sub = fleet.subscribe(broker, "pymb/#")
    sim = fleet.simulator("coolpro")
    db = tmp_path / "log.sqlite"
    bus = BusConfig("bus1", tcp=sim.endpoint, timeout=1.0, interval=0.02,
                    devices=[DeviceConfig("coolpro", 40)])
    cfg = LogConfig([bus], "sqlite", str(db))
    sink = _Counting(db)
    fw = Forwarder(str(db), MqttConfig(broker.url, node="live"), writer=sink)
    fw.start()
    logger = Logger(cfg, sink=ForwardingSink(sink, fw))
    seen: dict[str, set[int]] = {}

    def watch() -> None:
        # 100 samples at the subscriber, while the file (another connection) has none of them
        sub.wait_until(lambda m: len(plain_ids(m)) >= 100, 30, "100 samples live")
        seen["received"] = set(plain_ids(sub.snapshot()))
        seen["committed"] = _committed(db)
        logger.stop()

    t = threading.Thread(target=watch, daemon=True)
    t.start()
    try:
        summary = logger.run(60)
    finally:
        fw.stop(10)
        fw.join(20)
    t.join(5)
    assert fw.error is None, fw.error
    received, committed = seen["received"], seen["committed"]
    assert received - committed, "every sample received was committed already"
    # the mark's commit, the bus's and the broker's connection events, the close
    assert sink.commits <= 6, f"{sink.commits} commits for {summary.samples} samples"
    final = _committed(db)
    assert received <= final  # a clean stop commits everything published
    assert min(final) == 1
    con = sqlite3.connect(db)
    try:
        mark = int(con.execute("SELECT value FROM meta WHERE key = ?",
                               (RESERVED_KEY,)).fetchone()[0])
    finally:
        con.close()
    assert mark == max(final) < BLOCK  # brought down to the last id at the clean stop
