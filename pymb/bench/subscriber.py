"""The bench's MQTT subscriber (the ``fleet`` and ``month`` sections): a
persistent session (``clean_session`` false, QoS 1) that keeps every sample
message it receives, repeats included, so a section can count what arrived,
how often and how late."""

from __future__ import annotations

import json
import threading
import time
from typing import Any, NamedTuple

__all__ = ["Received", "Subscriber"]


class Received(NamedTuple):
    """One sample message as it came."""

    sample: int  #: the sample's id
    time_utc: float  #: the sample's time
    monotonic: float | None  #: the sample's monotonic stamp, if the message carries one
    at: float  #: ``time.time()`` when it came


class Subscriber:
    """Subscribes to ``topic`` on the broker at 127.0.0.1:``port`` as
    ``client_id`` and keeps each sample message (not the ``.../status``
    ones) in :attr:`got`, under :attr:`lock`. ``reconnect``: paho's
    shortest and longest wait before it connects again."""

    def __init__(self, port: int, topic: str, client_id: str,
                 reconnect: tuple[float, float] = (0.05, 0.2)) -> None:
        import paho.mqtt.client as mqtt  # the extra pymb-modbus[mqtt]
        from paho.mqtt.enums import CallbackAPIVersion
        self.got: list[Received] = []
        self.lock = threading.Lock()
        self.last = time.monotonic()  #: when the last message came
        subscribed = threading.Event()
        c = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=client_id, clean_session=False)
        # paho types the delays as int; it sleeps for them, so a fraction is a fraction
        c.reconnect_delay_set(*reconnect)  # type: ignore[arg-type]
        c.on_connect = lambda cl, u, f, rc, p: cl.subscribe(topic, qos=1)
        c.on_subscribe = lambda *a: subscribed.set()
        c.on_message = self._message
        c.connect("127.0.0.1", port, keepalive=5)
        c.loop_start()
        self.client = c
        if not subscribed.wait(15):
            self.close()
            raise RuntimeError("the bench's subscriber got no SUBACK")

    def _message(self, client: Any, userdata: Any, msg: Any) -> None:
        at = time.time()
        if msg.topic.endswith("/status"):
            return
        d = json.loads(msg.payload)
        mono = d.get("monotonic")
        got = Received(int(d["sample"]), float(d["time_utc"]),
                       None if mono is None else float(mono), at)
        with self.lock:
            self.got.append(got)
            self.last = time.monotonic()

    def ids(self) -> list[int]:
        """The id of each sample received, in the order they came, repeats included."""
        with self.lock:
            return [g.sample for g in self.got]

    def stamps(self) -> dict[int, set[float]]:
        """Each id received and the monotonic stamps it came with (a sample
        sent again carries its own stamp; another sample under a reused id
        would not)."""
        out: dict[int, set[float]] = {}
        with self.lock:
            for g in self.got:
                if g.monotonic is not None:
                    out.setdefault(g.sample, set()).add(g.monotonic)
        return out

    def wait(self, want: int, quiet: float, limit: float) -> None:
        """Until ``want`` distinct ids, or ``quiet`` s without news, at most ``limit`` s."""
        deadline = time.monotonic() + limit
        while time.monotonic() < deadline:
            if len(set(self.ids())) >= want or time.monotonic() - self.last > quiet:
                return
            time.sleep(0.05)

    def close(self) -> None:
        """Disconnect and stop paho's thread."""
        self.client.disconnect()
        self.client.loop_stop()
