"""``pymb demo --mqtt``: the demo's samples to a local mosquitto, watched.

With no URL it uses a broker already listening on 127.0.0.1:1883, else
starts Debian's mosquitto (when installed) on a free loopback port for the
demo's duration. A subscriber of its own counts what arrives, so the demo
can say how many of the logged samples the broker delivered.
"""

from __future__ import annotations

import json
import shlex
import socket
import tempfile
import threading
from collections.abc import Callable
from typing import Any, TextIO

from pymb.errors import InvalidArgument
from pymb.fleet.broker import Mosquitto, find_mosquitto
from pymb.fleet.config import MqttConfig
from pymb.fleet.forwarder import require_paho
from pymb.fleet.run import forwarding, summary_lines
from pymb.logger import LogConfig, Summary

__all__ = ["run_with_mqtt"]

NODE = "demo"


def _listening(port: int) -> bool:
    with socket.socket() as s:
        s.settimeout(0.5)
        return s.connect_ex(("127.0.0.1", port)) == 0


def run_with_mqtt(cfg: LogConfig, url: str, seconds: float, status: TextIO | None,
                  say: Callable[[str], None]) -> tuple[Summary, list[str]]:
    """Log ``cfg`` for ``seconds`` forwarding to ``url`` (``auto``: a local
    mosquitto); returns the logger's summary and the lines about MQTT."""
    require_paho()
    import paho.mqtt.client as mqtt
    from paho.mqtt.enums import CallbackAPIVersion
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
        cfg.mqtt = mcfg
        watch = shlex.join(["mosquitto_sub", "-h", mcfg.host, "-p", str(mcfg.port), "-t",
                            f"pymb/{NODE}/#", "-v"])
        whose = "a mosquitto started for the demo" if broker else "your broker"
        say(f"pymb demo: publishing every sample to {url} ({whose}); watch them with:\n"
            f"    {watch}")
        seen: set[int] = set()
        lock = threading.Lock()
        ready = threading.Event()

        def on_message(client: Any, userdata: Any, msg: Any) -> None:
            if not msg.topic.endswith("/status"):
                with lock:
                    seen.add(json.loads(msg.payload)["sample"])

        sub = mqtt.Client(CallbackAPIVersion.VERSION2, client_id="pymb-demo-watch")
        sub.on_connect = lambda c, u, f, rc, p: c.subscribe(f"pymb/{NODE}/#", qos=1)
        sub.on_subscribe = lambda *a: ready.set()
        sub.on_message = on_message
        if mcfg.tls:
            sub.tls_set()
        try:
            sub.connect(mcfg.host, mcfg.port)
        except OSError as e:
            raise InvalidArgument(f"--mqtt: cannot connect to {url}: {e}") from None
        sub.loop_start()
        ready.wait(10)
        try:
            summary, st = forwarding(cfg, mcfg, seconds=seconds, status=status)
        finally:
            sub.disconnect()
            sub.loop_stop()
        lines = [f"  mqtt:        {len(seen):,} of {summary.samples:,} samples received by a "
                 f"subscriber on {url}"] + [f"               {line[6:]}"
                                            for line in summary_lines(st)]
        if broker is None:
            lines.append(f"  watch:       {watch}")
        return summary, lines
    finally:
        if broker is not None:
            broker.stop()
        if tmp is not None:
            tmp.cleanup()
