"""``pymb bench --sections fleet``: samples through a local mosquitto.

Three publishers side by side, each fed the same synthetic CoolPro samples:

* pymb: samples committed to SQLite by the logger's sink, forwarded by
  :class:`pymb.fleet.forwarder.Forwarder` (plain profile, QoS 1, durable
  cursor);
* a plain paho publisher at QoS 0 and one at QoS 1 (paho's own in-memory
  queue and automatic reconnection), publishing each sample as it is taken:
  the approach the Modbus-to-MQTT bridges take.

Measured: throughput (a backlog of samples published as fast as the
publisher goes, until a subscriber has them all), end-to-end latency (sample
time to a subscriber, at a steady rate) and, across a 3 s broker outage
(mosquitto stopped and restarted mid-run), the samples lost and duplicated
as a persistent-session subscriber sees them.
"""

from __future__ import annotations

import json
import statistics
import tempfile
import threading
import time
from array import array
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

from pymb.bench.subscriber import Subscriber
from pymb.bench.table import percentile
from pymb.extras import install_hint

__all__ = ["run_fleet"]

OUTAGE_S = 3.0
RATE = 200.0  #: samples per second for the latency and outage runs


class _Paho:
    """A bridge-style publisher: each sample published as it is taken."""

    def __init__(self, mqtt: Any, port: int, qos: int, topic: str) -> None:
        self.qos, self.topic = qos, topic
        c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"bench-paho-{qos}")
        c.reconnect_delay_set(0.5, 4)
        c.max_inflight_messages_set(200)
        ready = threading.Event()
        c.on_connect = lambda *a: ready.set()
        c.connect("127.0.0.1", port, keepalive=15)
        c.loop_start()
        ready.wait(15)
        self.client = c

    def produce(self, i: int, t: float) -> None:
        body = json.dumps({"device": "coolpro-40", "sample": i, "time_utc": t,
                           "values": _VALUES})
        self.client.publish(self.topic, body, qos=self.qos)

    def flush(self) -> None:
        pass

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


_VALUES = {"input_voltage_v": 24.5, "input_current_a": 2.45, "output_voltage_v": 24.0,
           "output_current_a": 2.41, "temperature_c": 26.1, "uptime_s": 1, "status": 0}


class _Pymb:
    """The logger's SQLite sink (batches committed as the logger commits a
    batch of this rate: every COMMIT_INTERVAL) and the forwarder, which
    publishes from the open batch."""

    def __init__(self, db: Path, port: int, catchup_rate: float = 1000.0) -> None:
        from pymb import maps
        from pymb.devices.mapreading import MapReading
        from pymb.fleet import ForwardingSink
        from pymb.fleet.config import MqttConfig
        from pymb.fleet.forwarder import Forwarder
        from pymb.logger.config import COMMIT_INTERVAL
        from pymb.store import DeviceInfo, SqliteSink

        self._info = DeviceInfo("bus1", "bench", "coolpro", 40, "coolpro-40")
        # the telemetry of _VALUES, as the logger reads it: the map's decoding of its registers
        m = maps.builtin("coolpro")
        regs = array("H", [24500, 2450, 24000, 2410, 26100, 1, 0, 0])
        dec = maps.Decoder(m, [p.name for p in m.points.values() if p.group == "telemetry"])
        self._data = MapReading(m, "telemetry", dec.read(regs), dec.states(), regs)
        self.commit_interval = COMMIT_INTERVAL
        self.sink = SqliteSink(db)
        self.fw = Forwarder(str(db), MqttConfig(f"mqtt://127.0.0.1:{port}", node="bench",
                                                catchup_rate=catchup_rate), writer=self.sink)
        self.out = ForwardingSink(self.sink, self.fw)
        self.fw.start()
        self._last_commit = time.monotonic()
        self.ids: list[int] = []

    def produce(self, i: int, t: float) -> None:
        from pymb.store import Sample
        self.out.write(Sample(self._info, t, time.monotonic(), self._data))
        if time.monotonic() - self._last_commit >= self.commit_interval:
            self.flush()

    def flush(self) -> None:
        self.out.commit()
        self._last_commit = time.monotonic()

    def close(self) -> None:
        self.out.close()
        self.fw.stop(10)
        self.fw.join(20)


def _scenario(make: Callable[[], Any], sub: Subscriber, n: int, rate: float | None,
              broker: Any, quiet: float, outage_s: float = OUTAGE_S) -> dict[str, Any]:
    """Produce n samples (ids 1..n) at ``rate`` (None: as fast as possible); with
    ``broker``, stop it for ``outage_s`` from a third of the run."""
    pub = make()
    t0 = time.monotonic()
    outage: tuple[float, float] | None = None
    if broker is not None and rate:
        outage = (t0 + n / rate / 3, t0 + n / rate / 3 + outage_s)
    down = False
    for i in range(1, n + 1):
        if rate:
            delay = t0 + i / rate - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        if outage is not None:
            now = time.monotonic()
            if not down and now >= outage[0]:
                broker.stop()
                down = True
            elif down and now >= outage[1] and broker.proc is None:
                broker.start()
        pub.produce(i, time.time())
    pub.flush()
    produced = time.monotonic()
    if down and broker.proc is None:
        broker.start()
    sub.wait(n, quiet=quiet, limit=60.0)
    done = time.monotonic()
    pub.close()
    ids = sub.ids()
    with sub.lock:
        lat = [(g.at - g.time_utc) * 1000 for g in sub.got]
        last_rx = max((g.at for g in sub.got), default=time.time())
    first_tx = time.time() - (done - t0)
    dup = sum(c - 1 for c in Counter(ids).values())
    return {"sent": n, "received": len(set(ids) & set(range(1, n + 1))),
            "lost": n - len(set(ids) & set(range(1, n + 1))), "duplicates": dup,
            "latency_p50_ms": percentile(lat, 0.5) if lat else None,
            "latency_p95_ms": percentile(lat, 0.95) if lat else None,
            "seconds": last_rx - first_tx, "produce_s": produced - t0}


def run_fleet(quick: bool, say: Callable[[str], None]) -> dict[str, Any]:
    """The fleet section's result (JSON-able), or a skip reason."""
    try:
        import paho.mqtt.client as mqtt
    except ImportError:
        return {"status": "skipped",
                "reason": f"paho-mqtt is not installed ({install_hint('mqtt')})"}
    from pymb.fleet.broker import Mosquitto, find_mosquitto
    if find_mosquitto() is None:
        return {"status": "skipped", "reason": "mosquitto is not installed"}
    n_burst = 1000 if quick else 20000
    n_live = int(RATE * (0.5 if quick else 5))
    # --quick: a 1 s outage, pymb's publisher only (the bridges lose samples by
    # design; waiting out their silence costs most of the section), to fit its budget
    outage_s = 1.0 if quick else OUTAGE_S
    n_outage = int(RATE * (2 if quick else 12))
    quiet = 2.0 if quick else 8.0
    repeats = 1 if quick else 3  #: burst runs per publisher; the median is reported
    rows = []
    with tempfile.TemporaryDirectory(prefix="pymb-bench-fleet-") as tmp:
        broker = Mosquitto(Path(tmp) / "broker")
        broker.start()
        try:
            for label, qos, kind in (("pymb (SQLite outbox, QoS 1)", 1, "pymb"),
                                     ("paho, QoS 0", 0, "paho"),
                                     ("paho, QoS 1", 1, "paho")):
                row: dict[str, Any] = {"label": label, "qos": qos}
                bursts: list[float] = []
                runs = [("burst", n_burst, None, False)] * repeats + [
                    ("live", n_live, RATE, False)] + (
                    [("outage", n_outage, RATE, True)] if kind == "pymb" or not quick else [])
                for k, (what, n, rate, outage) in enumerate(runs):
                    say(f"fleet: {label}, {what} ({n} samples)")
                    topic = f"bench/{kind}{qos}/{what}{k}"
                    db = Path(tmp) / f"{kind}{qos}-{what}{k}.sqlite"

                    def make(db: Path = db, topic: str = topic, q: int = qos,
                             kd: str = kind, w: str = what) -> Any:
                        if kd == "pymb":
                            return _Pymb(db, broker.port, 1e9 if w == "burst" else 1000.0)
                        return _Paho(mqtt, broker.port, q, topic)

                    sub_topic = "pymb/bench/#" if kind == "pymb" else topic
                    sub = Subscriber(broker.port, sub_topic, f"bench-sub-{kind}{qos}-{what}{k}")
                    try:
                        r = _scenario(make, sub, n, rate, broker if outage else None, quiet,
                                      outage_s)
                    finally:
                        sub.close()
                    if what == "burst":
                        if r["seconds"] > 0:
                            bursts.append(n / r["seconds"])
                        row["burst_lost"] = row.get("burst_lost", 0) + r["lost"]
                    elif what == "live":
                        row["latency_p50_ms"] = r["latency_p50_ms"]
                        row["latency_p95_ms"] = r["latency_p95_ms"]
                    else:
                        row.update(outage_sent=r["sent"], outage_lost=r["lost"],
                                   outage_duplicates=r["duplicates"])
                row["throughput_per_s"] = statistics.median(bursts) if bursts else None
                rows.append(row)
        finally:
            broker.stop()
    return {"status": "ok", "rate": RATE, "outage_s": outage_s, "burst": n_burst,
            "repeats": repeats,
            "live": n_live, "outage_samples": n_outage, "rows": rows}
