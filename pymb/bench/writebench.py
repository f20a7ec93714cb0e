"""``pymb bench --sections writes``: a write command's latency, from its
arrival to its result, while the logger polls many Modbus TCP devices.

``pymb log`` polls N simulated Modbus TCP devices (``pymb simulate --count
N``, one port each) every second and forwards to a local mosquitto with
write commands allowed; a paho client publishes commands on
``pymb/bench/{device}/set`` one after the other, round the devices, and
times each from its publish to its result on ``.../set/result``. Beside it,
the wire time of the same write and its read back, with a client of its own
to one of the devices (no broker, no logger). Goal: p99 of the command at
most the wire time's p99 plus 50 ms.
"""

from __future__ import annotations

import contextlib
import json
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from pymb.bench.table import Table, percentile
from pymb.extras import install_hint

__all__ = ["GOAL_MARGIN_S", "run_writes", "tables"]

GOAL_MARGIN_S = 0.050  #: the command's p99 may exceed the wire's by this much

BENCH_MAP = """schema = "pymb.map/1"
[device]
id = "bench-setpoint"
table = "holding"
[groups]
fast = { interval = 1.0 }
[[point]]
name = "setpoint"
address = 0
type = "u16"
access = "rw"
valid = [0, 60000]
example = 1
[[block]]
name = "reading"
first = 1
count = 10
type = "u16"
group = "fast"
example = [1, 2, 3, 4, 5, 6, 7, 8, 9, 10]
"""


def _wire(port: int, n: int) -> list[float]:
    """Seconds of a write and its read back, ``n`` times, on a client of its own."""
    import pymb
    out = []
    with pymb.TcpClient("127.0.0.1", port, timeout=2.0) as c:
        for i in range(n):
            t0 = time.perf_counter()
            c.write_register(0, 1000 + i, slave=1)
            c.read_holding_registers(0, 1, slave=1)
            out.append(time.perf_counter() - t0)
    return out


class _Results:
    def __init__(self, port: int) -> None:
        import paho.mqtt.client as mqtt
        from paho.mqtt.enums import CallbackAPIVersion
        self.cond = threading.Condition()
        self.got: dict[str, float] = {}
        self.ready = threading.Event()
        c = mqtt.Client(CallbackAPIVersion.VERSION2, client_id="pymb-bench-writes")
        c.on_connect = lambda cl, u, f, rc, p: cl.subscribe("pymb/bench/+/set/result", qos=1)
        c.on_subscribe = lambda *a: self.ready.set()
        c.on_message = self._on
        c.connect("127.0.0.1", port, keepalive=30)
        sock: Any = c.socket()
        with contextlib.suppress(OSError, AttributeError):
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        c.loop_start()
        self.client = c

    def _on(self, client: Any, userdata: Any, msg: Any) -> None:
        now = time.perf_counter()
        cid = json.loads(msg.payload).get("id")
        with self.cond:
            self.got[str(cid)] = now
            self.cond.notify_all()

    def wait(self, cid: str, timeout: float) -> float | None:
        with self.cond:
            if self.cond.wait_for(lambda: cid in self.got, timeout):
                return self.got[cid]
        return None

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


def run_writes(quick: bool, say: Any) -> dict[str, Any]:
    """The section's result (JSON-able), or a skip reason."""
    try:
        import paho.mqtt.client  # noqa: F401
    except ImportError:
        return {"status": "skipped", "reason": f"needs {install_hint('mqtt')}"}
    from pymb.fleet.broker import Mosquitto, find_mosquitto
    from pymb.sim.tcp import parse_ports
    if find_mosquitto() is None:
        return {"status": "skipped", "reason": "needs mosquitto installed"}
    devices, commands = (10, 20) if quick else (100, 300)
    py = [sys.executable, "-m", "pymb"]
    with tempfile.TemporaryDirectory(prefix="pymb-bench-writes-") as tmp:
        map_file = Path(tmp) / "bench.toml"
        map_file.write_text(BENCH_MAP)
        # the broker sends each message at once (mosquitto's default waits for
        # the ACK of what is in flight: Nagle's algorithm)
        broker = Mosquitto(Path(tmp) / "broker", extra=("set_tcp_nodelay true",))
        broker.start()
        sim = subprocess.Popen([*py, "simulate", "--map", str(map_file), "bench-setpoint:1",
                                "--tcp", "127.0.0.1:0", "--count", str(devices)],
                               stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        log: subprocess.Popen[str] | None = None
        results: _Results | None = None
        try:
            assert sim.stdout is not None
            ports = [int(p) for p in parse_ports(sim.stdout.readline().strip()
                                                 .rpartition(":")[2])]
            cfg = Path(tmp) / "log.toml"
            lines = ['maps = ["bench.toml"]', "[writes]", 'allow = ["*/setpoint"]']
            for k, p in enumerate(ports):
                lines += ["[[bus]]", f'name = "b{k}"', f'tcp = "127.0.0.1:{p}"',
                          "[[bus.device]]", 'type = "bench-setpoint"', "address = 1",
                          f'name = "d{k}"']
            cfg.write_text("\n".join(lines) + "\n")
            say(f"writes: pymb log polling {devices} Modbus TCP devices")
            log = subprocess.Popen([*py, "log", "--config", str(cfg), "--out",
                                    str(Path(tmp) / "log.sqlite"), "--mqtt",
                                    f"mqtt://127.0.0.1:{broker.port}", "--mqtt-node", "bench",
                                    "--quiet"], stdout=subprocess.DEVNULL,
                                   stderr=subprocess.PIPE, text=True)
            results = _Results(broker.port)
            results.ready.wait(15)
            latencies = _commands(results, devices, commands, log)
            wire = _wire(ports[0], commands)
        finally:
            if results is not None:
                results.close()
            for proc in (log, sim):
                if proc is not None and proc.poll() is None:
                    proc.terminate()
                    try:
                        proc.wait(30)
                    except subprocess.TimeoutExpired:
                        proc.kill()
                        proc.wait(10)
            broker.stop()
    if not latencies:
        return {"status": "failed", "reason": "no command was answered"}
    p99, wire_p99 = percentile(latencies, 0.99), percentile(wire, 0.99)
    return {"status": "ok", "devices": devices, "commands": len(latencies),
            "p50_s": statistics.median(latencies), "p99_s": p99,
            "wire_p50_s": statistics.median(wire), "wire_p99_s": wire_p99,
            "goal_met": p99 <= wire_p99 + GOAL_MARGIN_S}


def _commands(results: _Results, devices: int, n: int,
              log: subprocess.Popen[str]) -> list[float]:
    """Publish ``n`` commands one after the other; the latencies of those
    answered. The first command of each device is retried until the logger
    has subscribed (not timed)."""
    c = results.client
    for k in range(devices):  # warm-up: the logger up, subscribed, each connection open
        for attempt in range(60):
            cid = f"warm-{k}-{attempt}"
            c.publish(f"pymb/bench/d{k}/set", json.dumps(
                {"id": cid, "values": {"setpoint": 1}}), qos=1)
            if results.wait(cid, 1.0) is not None or log.poll() is not None:
                break
    out = []
    stamp = time.time_ns()
    for i in range(n):
        cid = f"c-{stamp}-{i}"
        t0 = time.perf_counter()
        c.publish(f"pymb/bench/d{i % devices}/set", json.dumps(
            {"id": cid, "values": {"setpoint": 2 + i}}), qos=1)
        t1 = results.wait(cid, 10.0)
        if t1 is not None:
            out.append(t1 - t0)
    return out


def tables(section: dict[str, Any]) -> list[Table]:
    """The section's table."""
    if section.get("status") != "ok":
        return [Table("Writes", "", ["status"],
                      [[f"{section.get('status')}: {section.get('reason')}"]], [False], [])]

    def ms(v: float) -> str:
        return f"{v * 1000:.1f} ms"

    note = (f"a write command over MQTT (publish to result, QoS 1, mosquitto on 127.0.0.1) "
            f"while pymb log polls {section['devices']} Modbus TCP devices every second; "
            f"{section['commands']} commands one after the other; the wire: the same write "
            "and its read back on a client of its own")
    rows = [["command to result", ms(section["p50_s"]), ms(section["p99_s"])],
            ["wire: write + read back", ms(section["wire_p50_s"]), ms(section["wire_p99_s"])]]
    met = "met" if section["goal_met"] else "NOT met"
    footer = [f"goal: p99 at most the wire's p99 + {GOAL_MARGIN_S * 1000:.0f} ms: {met}"]
    return [Table("Writes", note, ["", "p50", "p99"], rows, [False, True, True], footer)]
