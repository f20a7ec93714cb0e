"""The collector's loop: MQTT in, rows committed, then the acknowledgements.

paho's thread only queues what arrives (``manual_ack``: paho sends no PUBACK
by itself). The collector's thread takes what is queued (at most
:data:`MAX_BATCH` messages), turns it into rows and hands them to a writer
(:mod:`pymb.collect.writers`), which writes them in one transaction; once it
is committed, and every batch before it, the collector's thread acknowledges
the batch's QoS 1 messages. While the database cannot be reached the batch is
held and written again (backing off from 0.5 s to 10 s); the broker sends no more than
:data:`RECEIVE_MAXIMUM` unacknowledged messages meanwhile and keeps the rest
in the collector's persistent session (MQTT 5, session expiry
:data:`SESSION_EXPIRY`). A message that arrived on an earlier connection is
not acknowledged: the broker sends it again on the new one.
"""

from __future__ import annotations

import contextlib
import queue
import socket
import ssl
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from pymb.collect.rows import BadInput, Batch, plain_sample, plain_topic
from pymb.collect.sparkplug import SparkplugHost
from pymb.collect.sqlstore import Store
from pymb.collect.writers import Job, Message, Writers
from pymb.errors import InvalidArgument, ModbusConnectionError
from pymb.fleet.config import PROFILES, MqttConfig
from pymb.fleet.profiles import NAMESPACE, host_state, state_payload
from pymb.fleet.takeover import TAKEN_OVER, Takeovers

if TYPE_CHECKING:  # the extra pymb-modbus[collect]
    from paho.mqtt.client import Client, ConnectFlags, DisconnectFlags, MQTTMessage
    from paho.mqtt.properties import Properties
    from paho.mqtt.reasoncodes import ReasonCode

__all__ = [
    "MAX_BATCH",
    "RECEIVE_MAXIMUM",
    "SESSION_EXPIRY",
    "CollectConfig",
    "CollectStats",
    "Collector",
]

MAX_BATCH = 2000  #: messages written in one transaction, at most
RECEIVE_MAXIMUM = 20000  #: unacknowledged messages the broker may send (MQTT 5)
SESSION_EXPIRY = 7 * 86400  #: seconds the broker keeps the session of a stopped collector
BAD_EVERY = 60.0  #: seconds: a topic's bad input is reported at most this often
#: messages waiting to be written, at most: beyond, a QoS 0 message (Sparkplug
#: data) is dropped, as QoS 0 allows (the host sees the seq gap and asks for a
#: rebirth); QoS 1 messages are bounded by RECEIVE_MAXIMUM
MAX_INBOX = 50000
#: seconds a Sparkplug collector that stops, its STATE offline published, keeps
#: storing what the boards sent before they saw it: until each board it has a
#: birth of said NDEATH, or nothing came for END_QUIET seconds, at most END_WAIT
END_WAIT, END_QUIET = 5.0, 1.0
RECONNECT_FIRST, RECONNECT_MAX = 1, 30  #: seconds: paho's reconnection backoff


@dataclass
class CollectConfig:
    """What ``pymb collect`` does: from which broker (``mqtt``: its URL, user,
    TLS, and the plain prefix or the Sparkplug group) into which ``out``."""

    mqtt: MqttConfig
    out: str
    profile: str = "plain"
    share: str | None = None
    host_id: str = ""
    client_id: str = ""

    def __post_init__(self) -> None:
        if self.profile not in PROFILES:
            raise InvalidArgument(f"unknown profile {self.profile!r}; use plain or sparkplug")
        host = socket.gethostname().split(".")[0] or "pymb"
        for what, value in (("share", self.share), ("host id", self.host_id or None),
                            ("client id", self.client_id or None)):
            if value is not None and (not value or any(c in value for c in "/+#$")
                                      or value != value.strip()):
                raise InvalidArgument(f"{what} {value!r} must be a non-empty name without "
                                      "'/', '+', '#', '$' or surrounding spaces")
        if self.share and self.profile == "sparkplug":
            raise InvalidArgument("--share is for the plain profile: a Sparkplug node's seq "
                                  "and aliases need all its messages in one host application")
        self.host_id = self.host_id or f"pymb-{host}"
        if not self.client_id:
            self.client_id = f"pymb-collect-{self.profile}-{host}" + (
                f"-{self.share}" if self.share else "")

    @property
    def topic(self) -> str:
        """The subscription (``$share/NAME/...`` with ``share``)."""
        t = (f"{self.mqtt.prefix}/+/+" if self.profile == "plain"
             else f"{NAMESPACE}/{self.mqtt.group}/#")
        return f"$share/{self.share}/{t}" if self.share else t


@dataclass
class CollectStats:
    """What the collector did so far (read by the status line)."""

    messages: int = 0
    rows: int = 0  #: rows stored
    duplicates: int = 0  #: rows already stored (delivered again)
    bad: int = 0  #: messages that were not what the profile publishes
    dropped: int = 0  #: QoS 0 messages dropped while MAX_INBOX messages waited
    batches: int = 0
    lag: float = 0.0  #: seconds from the newest sample's time to its commit, last batch
    db_ok: bool = True
    mqtt_ok: bool = False
    started: float = field(default_factory=time.monotonic)


class Collector:
    """One collector: ``run()`` until ``stop`` is set; ``event(text)`` reports.
    ``stores``: one connection per writer (several for PostgreSQL)."""

    def __init__(self, cfg: CollectConfig, stores: Sequence[Store],
                 event: Callable[[str], None]) -> None:
        import paho.mqtt.client as mqtt  # the extra pymb-modbus[collect]
        from paho.mqtt.enums import CallbackAPIVersion
        from paho.mqtt.packettypes import PacketTypes
        from paho.mqtt.properties import Properties

        self.cfg = cfg
        self.event = event
        self.stats = CollectStats()
        self.stop = threading.Event()
        self.inbox: queue.SimpleQueue[Message] = queue.SimpleQueue()
        self.generation = 0  #: counts connections; a message remembers its own
        self.connack = threading.Event()
        self.suback = threading.Event()  #: the broker took the subscription
        self.refused: str | None = None
        self.bad_said: dict[str, float] = {}
        self.dropped_said = 0
        self.dropped_at = -BAD_EVERY
        self.host: SparkplugHost | None = None
        self.born_ms = round(time.time() * 1000)
        self.closing = False  #: it stops: its own STATE offline is its own
        self.said_offline = False  #: its STATE offline of a clean stop is published
        #: message ids of its STATE online in flight (paho's thread), to tell a refusal
        self.state_mids: set[int] = set()
        self.state_said: set[str] = set()  #: the broker's reasons for refusing it, said
        c = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=cfg.client_id,
                        protocol=mqtt.MQTTv5, manual_ack=True)
        cfg.mqtt.secure(c, cfg.mqtt.password())
        c.reconnect_delay_set(RECONNECT_FIRST, RECONNECT_MAX)
        #: two collectors with one client id take the session from each other
        self.takeovers = Takeovers(cfg.client_id, "", RECONNECT_MAX,
                                   second="a second collector with this --client-id")
        self.reconnect = RECONNECT_FIRST  #: seconds: paho's next first wait
        c.max_inflight_messages_set(100)
        c.max_queued_messages_set(0)
        self.props = Properties(PacketTypes.CONNECT)  # type: ignore[no-untyped-call]
        self.props.SessionExpiryInterval = SESSION_EXPIRY
        self.props.ReceiveMaximum = RECEIVE_MAXIMUM
        if cfg.profile == "sparkplug":
            self.host = SparkplugHost(cfg.mqtt.group, cfg.host_id, self._send, event)
            c.will_set(self.host.state_topic, state_payload(False, self.born_ms), 1, True)
        c.on_connect = self._on_connect
        c.on_disconnect = self._on_disconnect
        c.on_connect_fail = self._on_connect_fail
        c.on_message = self._on_message
        c.on_subscribe = self._on_subscribe
        c.on_publish = self._on_publish
        self.client = c
        self.writers = Writers(stores, self.stop, event)  # last: its threads run from here

    # paho's thread
    def _on_connect(self, client: Client, userdata: object, flags: ConnectFlags,
                    rc: ReasonCode, props: Properties | None = None) -> None:
        if rc.is_failure:
            self.refused = (f"the broker refused the connection: {rc}"
                            f"{self.cfg.mqtt.credentials_words(rc.value)}")
            self.connack.set()
            return
        self.generation += 1
        self.state_mids.clear()  # (message ids are per connection)
        self.stats.mqtt_ok = True
        self.takeovers.up()
        if self.host is None:
            client.subscribe(self.cfg.topic, qos=1)
        else:  # Sparkplug 3.0: its own STATE too (not what it publishes), before it
            from paho.mqtt.subscribeoptions import SubscribeOptions

            client.subscribe([(self.cfg.topic, SubscribeOptions(qos=1)),
                              (self.host.state_topic, SubscribeOptions(qos=1, noLocal=True))])
            self._online(client)
        if self.connack.is_set():
            self.event(f"connected to {self.cfg.mqtt.url} again")
        self.connack.set()

    def _on_disconnect(self, client: Client, userdata: object, flags: DisconnectFlags,
                       rc: ReasonCode, props: Properties | None = None) -> None:
        was_up, self.stats.mqtt_ok = self.stats.mqtt_ok, False
        if not was_up or self.stop.is_set():
            return
        # paho reconnects after its backoff, which a CONNACK starts over: a
        # takeover's backoff is set here, as its first wait
        anew, line = self.takeovers.down(rc.is_failure, rc.value == TAKEN_OVER)
        self.reconnect = RECONNECT_FIRST if anew else min(2 * self.reconnect, RECONNECT_MAX)
        client.reconnect_delay_set(self.reconnect, RECONNECT_MAX)
        if line is not None:
            self.event(line)
        elif not self.takeovers.said:  # said once, not at each takeover
            self.event(f"lost the broker {self.cfg.mqtt.url}: {rc}; reconnecting")

    def _on_connect_fail(self, client: Client, userdata: object) -> None:
        self.takeovers.away()  # the broker was away: not a takeover

    def _on_subscribe(self, client: Client, userdata: object, mid: int, rcs: list[ReasonCode],
                      props: Properties | None = None) -> None:
        failed = [rc for rc in rcs if getattr(rc, "is_failure", False)]
        if rcs and getattr(rcs[0], "is_failure", False):
            self.refused = f"the broker refused the subscription to {self.cfg.topic}: {failed[0]}"
            if self.suback.is_set():  # again, after a reconnection (at the start: the error)
                self.event(self.refused)
        elif failed and self.host is not None:  # its own STATE: said, not an end
            self.event(f"the broker refused the subscription to {self.host.state_topic}: "
                       f"{failed[0]}; a STATE offline published there stays")
        self.suback.set()

    def _on_message(self, client: Client, userdata: object, msg: MQTTMessage) -> None:
        if self.host is not None and msg.topic == self.host.state_topic:
            self._own_state(client, msg)
            return
        if msg.qos == 0 and self.inbox.qsize() >= MAX_INBOX:
            self.stats.dropped += 1
            return
        self.inbox.put((self.generation, msg.mid, msg.qos, msg.topic, bytes(msg.payload)))

    def _own_state(self, client: Client, msg: MQTTMessage) -> None:
        """Another client said this host id offline (the will of a collector
        with this host id, gone, another program): Sparkplug 3.0 wants it
        online again at once, with its will's timestamp. Not while it stops;
        nor for the retained STATE the subscription brings (its own online
        follows it)."""
        if msg.qos:
            client.ack(msg.mid, msg.qos)
        state = host_state(bytes(msg.payload))
        if state is None or state[0] or msg.retain or self.closing or self.host is None:
            return
        self._online(client)
        self.event(f"{self.host.state_topic} said offline: published online again")

    def _online(self, client: Client) -> None:
        """Publish its STATE online (retained, QoS 1), its PUBACK looked at."""
        assert self.host is not None
        info = client.publish(self.host.state_topic, state_payload(True, self.born_ms), 1, True)
        self.state_mids.add(info.mid)

    def _on_publish(self, client: Client, userdata: object, mid: int, rc: ReasonCode,
                    props: Properties | None = None) -> None:
        if mid not in self.state_mids or self.host is None:
            return
        self.state_mids.discard(mid)
        if getattr(rc, "is_failure", False) and str(rc) not in self.state_said:
            # an ACL that denies the topic, say: boards waiting for this host wait on
            self.state_said.add(str(rc))
            self.event(f"the broker refused {self.host.state_topic} online ({rc}): boards "
                       f"with --mqtt-primary-host {self.host.host_id} publish nothing until "
                       "it takes it (published again on each connection)")

    def _send(self, topic: str, payload: bytes) -> None:
        self.client.publish(topic, payload, 0, False)

    # the collector's thread
    def connect(self, timeout: float = 15.0) -> None:
        """Connect (persistent session) and wait for the CONNACK and the SUBACK
        (from then on the broker keeps what comes for the collector); raises
        ModbusConnectionError when the broker cannot be reached or refuses."""
        m = self.cfg.mqtt
        try:
            self.client.connect(m.host, m.port, keepalive=m.keepalive, clean_start=False,
                                properties=self.props)
        except (OSError, ssl.SSLError) as e:
            why = m.tls_refusal(e) if isinstance(e, ssl.SSLError) else (e.strerror or str(e))
            raise ModbusConnectionError(f"cannot reach the broker {m.url}: {why}") from None
        self.client.loop_start()
        if (not self.connack.wait(timeout) or self.refused or not self.suback.wait(timeout)
                or self.refused):
            self.stats.mqtt_ok = False  # not a broker lost: the start failed
            self.client.loop_stop()
            with contextlib.suppress(Exception):
                self.client.disconnect()
            raise ModbusConnectionError(self.refused or f"no answer from the broker {m.url}")
        self.event(f"connected to {m.url} as {self.cfg.client_id}, subscribed to "
                   f"{self.cfg.topic}")

    def _take(self) -> list[Message]:
        try:
            first = self.inbox.get(timeout=0.2)
        except queue.Empty:
            return []
        batch = [first]
        with contextlib.suppress(queue.Empty):
            while len(batch) < MAX_BATCH:
                batch.append(self.inbox.get_nowait())
        return batch

    def _bad(self, topic: str, why: str) -> None:
        self.stats.bad += 1
        now = time.monotonic()
        if now - self.bad_said.get(topic, -BAD_EVERY) >= BAD_EVERY:
            self.bad_said[topic] = now
            self.event(f"bad input on {topic}: {why} (the message is not stored; "
                       f"{self.stats.bad} bad so far)")

    def _add(self, batch: Batch, topic: str, payload: bytes) -> None:
        """The rows of one message into the batch (bad input: counted, said)."""
        try:
            if self.host is not None:
                rows = self.host.rows(topic, payload)
                if rows:
                    batch.add_rows(rows)
                return
            where = plain_topic(topic, self.cfg.mqtt.prefix)
            if where is not None:
                batch.add_plain(where[0], where[1], plain_sample(payload))
        except BadInput as e:
            self._bad(topic, str(e))

    def _finish(self) -> bool:
        """Acknowledge the batches committed, in order; True when there was one."""
        any_done = False
        gen = self.generation
        s = self.stats
        for job in self.writers.finished():
            any_done = True
            if job.stored is None:  # given up at a stop: the broker sends it again
                continue
            for g, mid, qos, _topic, _payload in job.messages:
                if qos and g == gen:
                    self.client.ack(mid, qos)
            s.messages += len(job.messages)
            s.rows += job.stored
            s.duplicates += job.batch.rows - job.stored
            s.batches += 1
            if job.batch.newest is not None:
                s.lag = time.time() - job.batch.newest
        s.db_ok = self.writers.db_ok
        if s.dropped > self.dropped_said and time.monotonic() - self.dropped_at >= BAD_EVERY:
            self.event(f"dropped {s.dropped - self.dropped_said:,} QoS 0 messages: "
                       f"{MAX_INBOX:,} were waiting for the database")
            self.dropped_said, self.dropped_at = s.dropped, time.monotonic()
        return any_done

    def step(self) -> bool:
        """Acknowledge what was committed; take a batch, make its rows and hand
        them to a writer. False when nothing happened."""
        done = self._finish()
        if self.writers.full():
            self.writers.wait(0.2)
            return self._finish() or done
        batch = self._take()
        if not batch:
            return done
        rows = self.writers.batch()
        for _gen, _mid, _qos, topic, payload in batch:
            self._add(rows, topic, payload)
        self.writers.submit(Job(batch, rows))
        return True

    def run(self, tick: Callable[[], None] | None = None) -> CollectStats:
        """Collect until ``stop`` is set, then finish the batch in hand and
        disconnect (Sparkplug: STATE offline first). Raises StoreRefused when
        the database refuses the writes."""
        try:
            while not self.stop.is_set():
                self.step()
                if tick is not None:
                    tick()
            if self.host is not None:
                self._end_sparkplug(tick)
            self.writers.drain()  # the batches in hand: committed, or given up
            self._finish()
        finally:
            self.stop.set()
            self.writers.close()
            self.close()
        return self.stats

    def _end_sparkplug(self, tick: Callable[[], None] | None) -> None:
        """A clean stop of a host application: its STATE offline first, so that the
        boards that wait for it stop (NDEATH) and keep what they log; then what they
        sent before that is stored (QoS 0: the broker would not send it again),
        until each board with a birth said NDEATH or nothing came for END_QUIET s,
        at most END_WAIT s."""
        assert self.host is not None
        self._offline()
        nodes = self.host.nodes
        end = time.monotonic() + END_WAIT
        quiet = time.monotonic()
        while time.monotonic() < end:
            if not any(n.born for n in nodes.values()) and self.inbox.empty():
                break
            if self.step():
                quiet = time.monotonic()
            elif time.monotonic() - quiet >= END_QUIET:
                break
            if tick is not None:
                tick()

    def _offline(self) -> None:
        """Publish its STATE offline (once, while connected) and wait for the PUBACK."""
        self.closing = True
        if self.host is None or self.said_offline or not self.stats.mqtt_ok:
            return
        self.said_offline = True
        with contextlib.suppress(Exception):
            info = self.client.publish(self.host.state_topic,
                                       state_payload(False, self.born_ms), 1, True)
            info.wait_for_publish(5)

    def close(self) -> None:
        """Disconnect cleanly (unacknowledged messages stay in the session)."""
        c = self.client
        self._offline()
        with contextlib.suppress(Exception):
            c.disconnect()
        c.loop_stop()
