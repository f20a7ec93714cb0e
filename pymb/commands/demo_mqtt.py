"""``pymb demo --mqtt``: the demo's samples to a local mosquitto, watched.

With no URL it uses a broker already listening on 127.0.0.1:1883, else
starts Debian's mosquitto (when installed) on a free loopback port for the
demo's duration. A subscriber of its own (:class:`Watch`) counts what
arrives, so the demo can say how many of the logged samples the broker
delivered. The broker's acknowledgement (PUBACK) tells the forwarder that
the broker has taken a message, not that it has delivered it to the other
subscribers yet: before it counts, the demo waits (at most ``RECEIVE_WAIT``
seconds) until every sample the broker acknowledged has reached its
subscriber, and it says how many did not.
"""

from __future__ import annotations

import json
import shlex
import socket
import tempfile
import threading
import uuid
from collections.abc import Callable
from typing import Any, TextIO

from pymb.commands.forward import forwarding, summary_lines
from pymb.errors import InvalidArgument, ModbusConnectionError
from pymb.fleet.broker import Mosquitto, find_mosquitto
from pymb.fleet.config import MqttConfig
from pymb.fleet.session import require_paho
from pymb.logger import LogConfig, RunSummary
from pymb.store import Outbox
from pymb.store.outbox import last_sample_id

__all__ = ["RECEIVE_WAIT", "Watch", "run_with_mqtt"]

NODE = "demo"
#: seconds the demo's subscriber is given, once the forwarder has stopped, to receive
#: what the broker acknowledged
RECEIVE_WAIT = 10.0
SUBSCRIBE_WAIT = 10.0  #: seconds for the broker's SUBACK


class Watch:
    """A subscriber to ``topic`` that collects the ``sample`` ids of the plain
    profile's messages (anything else on the topic is ignored).

    :meth:`wait_for` waits until given ids have arrived: a QoS 1 message the
    broker acknowledged to its publisher may still be on its way to the other
    subscribers.
    """

    def __init__(self, mcfg: MqttConfig, topic: str) -> None:
        import paho.mqtt.client as mqtt  # the optional extra pymb-modbus[mqtt]
        from paho.mqtt.enums import CallbackAPIVersion
        self.url, self.host, self.port = mcfg.url, mcfg.host, mcfg.port
        self.ids: set[int] = set()  #: the sample ids received so far (under ``cond``)
        self.cond = threading.Condition()
        self.refused: str | None = None  #: why the broker refused the subscription
        self._subscribed = threading.Event()
        # an id of its own: two demos on one broker must not take over each other's session
        self.client = mqtt.Client(CallbackAPIVersion.VERSION2,
                                  client_id=f"pymb-demo-watch-{uuid.uuid4().hex[:12]}")
        self.client.on_connect = lambda c, u, f, rc, p: c.subscribe(topic, qos=1)
        self.client.on_subscribe = self._on_subscribe
        self.client.on_message = self._on_message
        if mcfg.tls:
            self.client.tls_set(ca_certs=mcfg.ca)

    def _on_subscribe(self, client: Any, userdata: Any, mid: int, rcs: Any, props: Any) -> None:
        bad = [rc for rc in rcs if rc.is_failure]
        if bad:
            self.refused = str(bad[0])
        self._subscribed.set()

    def _on_message(self, client: Any, userdata: Any, msg: Any) -> None:
        try:
            sample = json.loads(msg.payload)["sample"]
        except (ValueError, TypeError, KeyError):  # the status topic, or not pymb's
            return
        if isinstance(sample, int):
            with self.cond:
                self.ids.add(sample)
                self.cond.notify_all()

    def start(self, timeout: float = SUBSCRIBE_WAIT) -> bool:
        """Connect and subscribe; False if the broker did not confirm the
        subscription within ``timeout`` or refused it (``refused`` says why)."""
        try:
            self.client.connect(self.host, self.port)
        except OSError as e:
            # as pymb collect says it: a connection that failed, exit 4
            raise ModbusConnectionError(f"--mqtt: cannot connect to {self.url}: {e}") from None
        self.client.loop_start()
        return self._subscribed.wait(timeout) and self.refused is None

    def wait_for(self, ids: set[int], timeout: float) -> set[int]:
        """Wait until every id of ``ids`` has arrived, or ``timeout`` seconds
        passed; the ids of ``ids`` that arrived."""
        with self.cond:
            self.cond.wait_for(lambda: ids <= self.ids, timeout)
            return ids & self.ids

    def close(self) -> None:
        """Disconnect."""
        self.client.disconnect()
        self.client.loop_stop()


def _listening(port: int) -> bool:
    with socket.socket() as s:
        s.settimeout(0.5)
        return s.connect_ex(("127.0.0.1", port)) == 0


def run_with_mqtt(cfg: LogConfig, url: str, seconds: float, status: TextIO | None,
                  say: Callable[[str], None]) -> tuple[RunSummary, list[str]]:
    """Log ``cfg`` for ``seconds`` forwarding to ``url`` (``auto``: a local
    mosquitto); returns the logger's summary and the lines about MQTT."""
    require_paho()
    broker: Mosquitto | None = None
    tmp: tempfile.TemporaryDirectory[str] | None = None
    if url == "auto":
        if _listening(1883):
            url = "mqtt://127.0.0.1:1883"
        elif find_mosquitto() is not None:
            tmp = tempfile.TemporaryDirectory(prefix="pymb-demo-mosquitto-")
            broker = Mosquitto(tmp.name)
            broker.start()
            url = broker.url
        else:
            raise InvalidArgument("--mqtt: no broker on 127.0.0.1:1883 and mosquitto is not "
                                  "installed (apt-get install mosquitto); or give "
                                  "--mqtt mqtt://HOST[:PORT]")
    try:
        mcfg = MqttConfig(url, node=NODE)
        watch_cmd = shlex.join(["mosquitto_sub", "-h", mcfg.host, "-p", str(mcfg.port),
                                "-t", f"pymb/{NODE}/#", "-v"])
        whose = "a mosquitto started for the demo" if broker else "your broker"
        say(f"pymb demo: publishing every sample to {url} ({whose}); watch them with:\n"
            f"    {watch_cmd}")
        before = last_sample_id(cfg.path)  # --out an existing database: not our samples
        watch = Watch(mcfg, f"pymb/{NODE}/#")
        subscribed = watch.start()
        try:
            summary, st = forwarding(cfg, mcfg, seconds=seconds, status=status)
            src = Outbox(cfg.path)
            try:
                ours = src.ids_after(before)
            finally:
                src.close()
            acked = {i for i in ours if i <= st.cursor}
            got = watch.wait_for(acked, RECEIVE_WAIT) if subscribed else set()
            received = watch.wait_for(ours, 0)  # and any acknowledged above the cursor
        finally:
            watch.close()
        if subscribed:
            lines = [f"  mqtt:        {len(received):,} of {summary.samples:,} samples received "
                     f"by a subscriber on {url}"]
            if len(got) < len(acked):
                lines.append(f"               {len(acked) - len(got):,} samples acknowledged by "
                             f"the broker did not reach it within {RECEIVE_WAIT:g} s")
        else:
            why = f"the broker refused it ({watch.refused})" if watch.refused else \
                f"no SUBACK within {SUBSCRIBE_WAIT:g} s"
            lines = [f"  mqtt:        the demo's subscriber to pymb/{NODE}/# on {url} could not "
                     f"subscribe: {why}; received samples not counted"]
        lines += [f"               {line[6:]}" for line in summary_lines(st)]
        if broker is None:
            lines.append(f"  watch:       {watch_cmd}")
        return summary, lines
    finally:
        if broker is not None:
            broker.stop()
        if tmp is not None:
            tmp.cleanup()
