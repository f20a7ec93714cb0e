"""Fixtures and helpers for the fleet tests: Debian's mosquitto on a free
127.0.0.1 port (plain, TLS with certificates made here, a password file),
stopped by its PID; a paho subscriber that records what it receives; the
Sparkplug B payload schema of an independent implementation (pysparkplug);
pymb log as a child."""

from __future__ import annotations

import json
import signal
import sqlite3
import subprocess
import threading
from collections import Counter
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from conftest import PYMB, PYMB_ENV, wait_until

from pymb.fleet.broker import Certificates, Mosquitto, find_mosquitto, make_certificates
from pymb.sim import SimulatorProcess

paho = pytest.importorskip("paho.mqtt.client")

@pytest.fixture
def mosquitto(tmp_path: Path) -> Iterator[Callable[..., Mosquitto]]:
    """A factory of started brokers (keyword arguments as Mosquitto's), all stopped
    by their PIDs at teardown."""
    if find_mosquitto() is None:
        pytest.fail("mosquitto is not installed: .ci/setup installs it")
    started: list[Mosquitto] = []

    def make(**kw: Any) -> Mosquitto:
        b = Mosquitto(tmp_path / f"broker{len(started)}", **kw)
        b.start()
        started.append(b)
        return b

    yield make
    for b in started:
        b.stop()


@pytest.fixture(scope="session")
def certificates(tmp_path_factory: pytest.TempPathFactory) -> Certificates:
    """A CA, a server certificate for 127.0.0.1 and a client certificate."""
    return make_certificates(tmp_path_factory.mktemp("tls"))


@pytest.fixture
def simulator() -> Iterator[str]:
    """A simulated CoolPro (address 40) on Modbus TCP in its own process: HOST:PORT."""
    sim = SimulatorProcess(["coolpro", "--tcp", "127.0.0.1:0"], quiet=True).start()
    try:
        yield sim.endpoint
    finally:
        sim.stop()


class Subscriber:
    """A paho subscriber with a persistent session (QoS 1), reconnecting by itself;
    ``messages`` is every (topic, payload) received, in order."""

    def __init__(self, broker: Mosquitto, topic: str, *, client_id: str = "pymb-test-sub",
                 tls: Certificates | None = None, user: tuple[str, str] | None = None) -> None:
        self.messages: list[tuple[str, bytes]] = []
        self.flags: list[tuple[int, bool]] = []  #: (QoS, retain) of each message
        self.lock = threading.Lock()
        self.arrived = threading.Condition(self.lock)  #: notified on each message
        self.subscribed = threading.Event()
        c = paho.Client(paho.CallbackAPIVersion.VERSION2, client_id=client_id,
                        clean_session=False)
        if tls is not None:
            c.tls_set(ca_certs=tls.ca, certfile=tls.client_cert, keyfile=tls.client_key)
        if user is not None:
            c.username_pw_set(*user)
        c.reconnect_delay_set(0.05, 0.2)
        c.on_connect = lambda cl, u, f, rc, p: cl.subscribe(topic, qos=1)
        c.on_subscribe = lambda *a: self.subscribed.set()
        c.on_message = self._on_message
        self.client = c
        c.connect("127.0.0.1", broker.port, keepalive=5)
        c.loop_start()
        wait_until(self.subscribed.is_set, "the test subscriber's SUBACK", 15)

    def _on_message(self, client: Any, userdata: Any, msg: Any) -> None:
        with self.lock:
            self.messages.append((msg.topic, bytes(msg.payload)))
            self.flags.append((msg.qos, bool(msg.retain)))
            self.arrived.notify_all()

    def wait_until(self, pred: Callable[[list[tuple[str, bytes]]], Any], timeout: float,
                   what: str) -> Any:
        """Wait, woken by each message (no polling), until ``pred`` of the messages
        received so far is true; fail after ``timeout``. ``pred`` must not keep or
        change the list it is given."""
        with self.arrived:
            got = self.arrived.wait_for(lambda: pred(self.messages), timeout)
        if not got:
            raise AssertionError(f"timed out after {timeout:g} s waiting for {what}")
        return got

    def snapshot(self) -> list[tuple[str, bytes]]:
        """A copy of what was received so far."""
        with self.lock:
            return list(self.messages)

    def close(self) -> None:
        """Disconnect."""
        self.client.disconnect()
        self.client.loop_stop()


class Fleet:
    """One fleet test's parts, all stopped at its end even when it fails: the
    brokers (the ``mosquitto`` fixture), subscribers, simulators in their own
    processes and ``pymb log`` children (killed if still running)."""

    def __init__(self, make_broker: Callable[..., Mosquitto], tmp_path: Path) -> None:
        self.make_broker = make_broker
        self.tmp = tmp_path
        self.subscribers: list[Subscriber] = []
        self.simulators: list[SimulatorProcess] = []
        self.children: list[subprocess.Popen[str]] = []

    def broker(self, **kw: Any) -> Mosquitto:
        """A started broker (keyword arguments as Mosquitto's)."""
        return self.make_broker(**kw)

    def subscribe(self, broker: Mosquitto, topic: str, **kw: Any) -> Subscriber:
        """A connected, subscribed Subscriber (keyword arguments as its)."""
        sub = Subscriber(broker, topic, **kw)
        self.subscribers.append(sub)
        return sub

    def simulator(self, *devices: str, port: int = 0) -> SimulatorProcess:
        """``pymb simulate DEVICES --tcp 127.0.0.1:PORT`` in its own process."""
        sim = SimulatorProcess([*devices, "--tcp", f"127.0.0.1:{port}"], quiet=True).start()
        self.simulators.append(sim)
        return sim

    def log(self, endpoint: str, db: Path, *mqtt: str, **kw: Any) -> subprocess.Popen[str]:
        """``start_log``, the child killed at the end if it still runs."""
        proc = start_log(endpoint, db, *mqtt, **kw)
        self.children.append(proc)
        return proc

    def pymb(self, *argv: str) -> subprocess.Popen[str]:
        """``python -m pymb ARGV`` started, killed at the end if it still runs."""
        proc = subprocess.Popen([*PYMB, *argv], stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True, env=PYMB_ENV)
        self.children.append(proc)
        return proc

    def close(self) -> None:
        """Kill what still runs, disconnect the subscribers, stop the simulators."""
        for proc in self.children:
            if proc.poll() is None:
                proc.kill()
                proc.communicate(timeout=30)
        for sub in self.subscribers:
            sub.close()
        for sim in self.simulators:
            sim.stop()


@pytest.fixture
def fleet(mosquitto: Callable[..., Mosquitto], tmp_path: Path) -> Iterator[Fleet]:
    """A :class:`Fleet` for the test; its brokers stop (by PID) after the rest."""
    f = Fleet(mosquitto, tmp_path)
    try:
        yield f
    finally:
        f.close()


def plain_ids(messages: list[tuple[str, bytes]]) -> list[int]:
    """The sample ids of the plain profile's data messages (not the retained
    status, nor a map device's retained metadata)."""
    return [json.loads(p)["sample"] for t, p in messages
            if not t.endswith(("/status", "/meta"))]


def db_ids(path: Path) -> set[int]:
    """The sample ids in a pymb database."""
    con = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    try:
        return {i for (i,) in con.execute("SELECT id FROM samples")}
    finally:
        con.close()


def db_count(path: Path) -> int:
    """The number of samples in a database (0 while it does not exist yet)."""
    if not path.exists():
        return 0
    try:
        return len(db_ids(path))
    except sqlite3.Error:
        return 0


def db_events(path: Path, word: str, kind: str = "mqtt") -> list[str]:
    """The messages of ``kind``'s events in a pymb database that contain
    ``word`` (none while the database or its tables are not there yet)."""
    if not path.exists():
        return []
    con = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    try:
        return [m for (m,) in con.execute(
            "SELECT message FROM events WHERE kind = ? ORDER BY id", (kind,)) if word in m]
    except sqlite3.Error:
        return []
    finally:
        con.close()


def restart_broker_mid_run(broker: Mosquitto, sub: Subscriber, db: Path) -> None:
    """Once 50 plain samples came live, stop ``broker`` until 100 more are logged into
    ``db`` while it is down, start it again and wait for live samples past the outage."""
    wait_until(lambda: len(plain_ids(sub.snapshot())) >= 50, "50 samples live", 30)
    broker.stop()
    before = db_count(db)
    wait_until(lambda: db_count(db) >= before + 100, "100 samples logged while down", 30)
    broker.start()
    wait_until(lambda: max(plain_ids(sub.snapshot())) > before + 100,
               "live samples after the restart", 30)


def duplicates(ids: list[int]) -> int:
    """Ids received more than once, counted once per extra copy."""
    return sum(n - 1 for n in Counter(ids).values())


def start_log(endpoint: str, db: Path, *mqtt: str, env: dict[str, str] | None = None,
              seconds: float | None = None, device: str = "coolpro:40",
              commit: float | None = 1.0) -> subprocess.Popen[str]:
    """``pymb log`` of the simulated CoolPro into ``db``, forwarding as ``mqtt``
    says, committing every ``commit`` seconds: the tests watch the database
    from outside (None: the logger's own rule, which commits a few hundred
    samples within 1.5 s; the forwarder publishes them before that)."""
    args = [*PYMB, "log", "--tcp", endpoint, "--device", device,
            "--interval", "0.01", "--out", str(db), *mqtt]
    if commit is not None:
        args += ["--commit-interval", f"{commit:g}"]
    if seconds is not None:
        args += ["--seconds", str(seconds)]
    return subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**PYMB_ENV, **(env or {})})


def stop_log(proc: subprocess.Popen[str], timeout: float = 30) -> str:
    """SIGTERM (a clean end: the forwarder drains); returns stderr."""
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=timeout)
    assert proc.returncode == 0, err
    return err


@pytest.fixture(scope="session")
def sparkplug_pb() -> Any:
    """The Sparkplug B ``Payload`` message class of pysparkplug, an implementation of
    Sparkplug B independent of pymb's own encoder (``pymb.fleet.protobuf``): the
    specification's ``sparkplug_b.proto`` compiled by protoc, decoded by the protobuf
    runtime."""
    try:
        from pysparkplug._protobuf import Payload
    except ImportError:
        pytest.fail("pysparkplug is not installed: the test extra installs it")
    return Payload
