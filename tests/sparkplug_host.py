"""A Sparkplug host for the DCMD write tests (tests/writes): publishes DCMDs
and decodes what the node publishes with pysparkplug's ``Payload``
(protobuf's runtime, independent of pymb's own encoder); ``pymb log
--mqtt-profile sparkplug`` with writes allowed, as a child."""

from __future__ import annotations

import subprocess
import time
from pathlib import Path
from typing import Any

from conftest import PYMB, PYMB_ENV
from mqtt_broker import Fleet, paho
from write_peers import FreezingPtyPeer

GROUP, NODE, DEVICE = "plant", "n1", "psu-a"
DOUBLE, UINT16, BOOLEAN, INT16 = 10, 6, 11, 2  # Sparkplug B datatypes


def start(fleet: Fleet, broker: Any, peer: FreezingPtyPeer | None, map_file: Path,
          db: Path, *line: str, unit: int = 1) -> subprocess.Popen[str]:
    """``pymb log`` of the device (``unit``) on ``peer``'s pty (or on ``line``:
    ``--tcp HOST:PORT``, ``--port PATH``)."""
    where = line or ("--port", peer.port if peer else "", "--baud", "19200")
    proc = subprocess.Popen(
        [*PYMB, "log", "--map", str(map_file), *where,
         "--device", f"wdev:{unit},name={DEVICE}", "--interval", "0.2", "--out", str(db),
         "--mqtt", f"mqtt://127.0.0.1:{broker.port}", "--mqtt-profile", "sparkplug",
         "--mqtt-group", GROUP, "--mqtt-node", NODE,
         "--allow-writes", f"{DEVICE}/setpoint_hz", "--allow-writes", f"{DEVICE}/mode",
         "--allow-writes", f"{DEVICE}/firmware", "--allow-writes", f"{DEVICE}/zone_c_2",
         "--quiet"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=PYMB_ENV)
    fleet.children.append(proc)
    return proc


class Host:
    """A Sparkplug host: publishes DCMDs, decodes what the node publishes."""

    def __init__(self, fleet: Fleet, broker: Any, pb: Any, group: str = GROUP,
                 node: str = NODE, device: str = DEVICE) -> None:
        self.pb = pb
        self.device_topic = f"spBv1.0/{group}/{{}}/{node}/{device}"
        self.sub = fleet.subscribe(broker, f"spBv1.0/{group}/#", client_id="pymb-test-host")
        c = paho.Client(paho.CallbackAPIVersion.VERSION2, client_id="pymb-test-dcmd")
        c.connect("127.0.0.1", broker.port, keepalive=5)
        c.loop_start()
        self.client = c
        self.stamp = int(time.time() * 1000)

    def decoded(self, kind: str, start: int = 0,
                messages: list[tuple[str, bytes]] | None = None) -> list[Any]:
        """The payloads of ``kind`` from message ``start`` on (of ``messages``:
        inside a wait, which holds the subscriber's lock)."""
        out = []
        for topic, payload in (self.sub.snapshot() if messages is None else messages)[start:]:
            if topic == self.device_topic.format(kind):
                p = self.pb()
                p.ParseFromString(payload)
                out.append(p)
        return out

    def birth(self) -> Any:
        self.sub.wait_until(lambda ms: any("/DBIRTH/" in t for t, _ in ms), 60, "a DBIRTH")
        return self.decoded("DBIRTH")[-1]

    def dcmd(self, *metrics: tuple[str | int, int, Any], seq: int | None = None,
             timestamp: int | None = None) -> bytes:
        """Publish a DCMD of (name or alias, datatype, value) metrics; its payload."""
        p = self.pb()
        self.stamp += 1
        p.timestamp = self.stamp if timestamp is None else timestamp
        if seq is not None:
            p.seq = seq
        for key, dt, value in metrics:
            m = p.metrics.add()
            if isinstance(key, str):
                m.name = key
            else:
                m.alias = key
            m.datatype = dt
            field = {DOUBLE: "double_value", BOOLEAN: "boolean_value"}.get(dt, "int_value")
            setattr(m, field, value)
        return self.send(p.SerializeToString())

    def send(self, payload: bytes) -> bytes:
        self.client.publish(self.device_topic.format("DCMD"), payload,
                            qos=0).wait_for_publish(5)
        return payload

    def answer(self, start: int, aliases: dict[str, int]) -> dict[str, Any]:
        """The DDATA that answers a DCMD (no ``sample`` metric): name -> value."""
        names = {a: n for n, a in aliases.items()}

        def found(ms: list[tuple[str, bytes]]) -> Any:
            for d in self.decoded("DDATA", start, ms):
                got = {names[m.alias]: value_of(m) for m in d.metrics}
                if "sample" not in got:
                    return got
            return None
        got: dict[str, Any] = self.sub.wait_until(found, 60, "the DDATA of a DCMD")
        return got

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()
        self.sub.close()


def value_of(m: Any) -> Any:
    kind = m.WhichOneof("value")
    return None if kind is None else getattr(m, kind)
