"""Helpers of the MQTT write tests (tests/writes): ``pymb log`` with write
commands allowed as a child, a paho client that publishes commands and
waits for their results, and what the scripted device was sent."""

from __future__ import annotations

import json
import signal
import sqlite3
import subprocess
import time
from pathlib import Path
from typing import Any

from conftest import PYMB, PYMB_ENV, wait_until
from mqtt_broker import Fleet, paho
from write_peers import Freezing, FreezingPtyPeer

WRITES = (5, 6, 15, 16, 22)  #: function codes that write
SET = "pymb/n1/psu-a/set"


def writes_sent(peer: Freezing) -> list[bytes]:
    return [pdu for _, pdu in list(peer.requests) if pdu[0] in WRITES]


def start(fleet: Fleet, broker: Any, peer: FreezingPtyPeer | None, map_file: Path,
          db: Path, *line: str) -> subprocess.Popen[str]:
    where = line or ("--port", peer.port if peer else "", "--baud", "19200")
    proc = subprocess.Popen(
        [*PYMB, "log", "--map", str(map_file), *where,
         "--device", "wdev:1,name=psu-a", "--interval", "0.2", "--out", str(db),
         "--mqtt", f"mqtt://127.0.0.1:{broker.port}", "--mqtt-node", "n1",
         "--allow-writes", "psu-a/setpoint_hz", "--allow-writes", "psu-a/mode",
         "--allow-writes", "psu-a/relay_*", "--quiet"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=PYMB_ENV)
    fleet.children.append(proc)
    return proc


class Commander:
    """A paho client that publishes commands (QoS 1) and waits for their results."""

    def __init__(self, fleet: Fleet, broker: Any) -> None:
        self.results = fleet.subscribe(broker, SET + "/result", client_id="pymb-test-results")
        c = paho.Client(paho.CallbackAPIVersion.VERSION2, client_id="pymb-test-commander")
        c.reconnect_delay_set(0.05, 0.2)
        c.connect("127.0.0.1", broker.port, keepalive=5)
        c.loop_start()
        self.client = c

    def send(self, command: Any, *, raw: bytes | None = None, timeout: float = 30) -> Any:
        """Publish until its result comes (the logger subscribes once it is up)."""
        payload = raw if raw is not None else json.dumps(command).encode()
        cid = command.get("id") if isinstance(command, dict) else None
        n = len(self.results.snapshot())
        deadline_each = 1.0
        for _ in range(int(timeout / deadline_each)):
            if n == len(self.results.snapshot()):
                try:
                    self.client.publish(SET, payload, qos=1).wait_for_publish(5)
                except (RuntimeError, ValueError):  # not connected (a broker restart): again
                    time.sleep(deadline_each)
                    continue
            got = self._wait(n, cid, deadline_each)
            if got is not None:
                return got
        raise AssertionError(f"no result for {command!r}")

    def _wait(self, n: int, cid: Any, timeout: float) -> Any:
        def found(msgs: list[tuple[str, bytes]]) -> Any:
            for _, p in msgs[n:]:
                doc = json.loads(p)
                if doc.get("id") == cid:
                    return doc
            return None
        try:
            return self.results.wait_until(found, timeout, "a result")
        except AssertionError:
            return None

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


def rows(db: Path) -> list[tuple[Any, ...]]:
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    try:
        return con.execute("SELECT source, command_id, device, point, requested, before, "
                           "after, ok, reason FROM writes").fetchall()
    finally:
        con.close()


def stop(proc: subprocess.Popen[str], code: int = 0) -> str:
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == code, err
    return err




def clean_polls_after_the_writes(peer: Freezing, polls: int = 3) -> None:
    """Wait until the peer logged ``polls`` polls after its last write (the
    commands may come faster than the polls: every run between two polls
    then holds one)."""
    def after() -> int:
        log = [pdu[:5] for _, pdu in list(peer.requests)]
        last = max((i for i, p in enumerate(log) if p[0] in WRITES), default=-1)
        return sum(1 for p in log[last + 1:] if p == log[0])
    wait_until(lambda: after() >= polls, f"{polls} polls after the last write", 30)
