"""One MQTT connection of the forwarder: a paho client and its callbacks,
which run on paho's thread and only record what happened (acknowledgements,
a lost connection, a command, the primary host's state) for the forwarder's
thread, which they wake.

A logger that takes the plain profile's write commands over MQTT 5 keeps a
persistent session (clean start off, :data:`COMMAND_SESSION_EXPIRY` seconds
of session expiry, ended by a clean stop) and acknowledges each command only
once it is answered: a command delivered to a logger that stops before its
answer is delivered again when the logger comes back, and answered then (from
the record when it was on record). Sparkplug B asks its edge nodes for clean
sessions; MQTT 3.1.1 has no session expiry, so both keep clean sessions."""

from __future__ import annotations

import collections
import contextlib
import socket
import threading
from collections.abc import Callable
from typing import Any, Protocol

from pymb.errors import InvalidArgument
from pymb.extras import install_hint
from pymb.fleet.config import MqttConfig
from pymb.fleet.profiles import Profile, host_state
from pymb.fleet.takeover import TAKEN_OVER

__all__ = ["COMMAND_SESSION_EXPIRY", "Session", "require_paho"]

#: seconds the broker keeps a commands-taking logger's session after it is gone
#: (a crash and a restart by the service manager keep it; a longer absence drops it,
#: and the commands it holds, so no command waits longer for a logger to come back)
COMMAND_SESSION_EXPIRY = 60


def require_paho() -> None:
    """Raise InvalidArgument, saying how to install it, when paho-mqtt is missing."""
    try:
        import paho.mqtt.client  # noqa: F401
    except ImportError:
        raise InvalidArgument(f"--mqtt needs paho-mqtt: {install_hint('mqtt')}") from None


class _Owner(Protocol):
    """What a session tells the forwarder that owns it."""

    cfg: MqttConfig
    profile: Profile
    wake: threading.Event
    rebirth: threading.Event
    host_ts: float | None
    host_online_ts: float | None
    #: set topic -> device: the plain profile's write commands (empty: none)
    set_topics: dict[str, str]

    def command_arrived(self, topic: str, payload: bytes,
                        done: Callable[[], None] | None = None, *,
                        retained: bool = False) -> None:
        """A write command arrived on one of ``set_topics``; ``done()``, once it is
        answered, acknowledges it to the broker (None: acknowledged already);
        ``retained``: the broker held it retained from before the subscription."""

    def record_event(self, message: str) -> None:
        """Add a line to the connection's story."""

    def subscription_refused(self, topic: str, reason: str) -> None:
        """The broker refused the subscription to ``topic`` (its SUBACK's reason)."""


class Session:
    """One MQTT connection (a paho client); callbacks run on paho's thread."""

    def __init__(self, fw: _Owner, client_id: str, window: int) -> None:
        import paho.mqtt.client as mqtt  # the optional extra pymb-modbus[mqtt]
        from paho.mqtt.enums import CallbackAPIVersion

        self.fw = fw
        #: PUBACK/SUBACK message ids, each with the broker's reason when it refused
        #: the message (MQTT 5; None: taken); per connection, as paho numbers them anew
        self.acks: collections.deque[tuple[int, str | None]] = collections.deque()
        self.connack = threading.Event()
        self.reason: str | None = None
        self.ok = False
        self.lost = False
        #: the broker ended the connection (not this side, no other reason known)
        self.ended_by_broker = False
        self.taken_over = False  #: the broker said "session taken over" (MQTT 5)
        self.again = False  #: ended by the forwarder to offer refused samples again
        self.host_online = False  #: the primary host's STATE said online (on this connection)
        #: SUBSCRIBE message id -> topic of the subscriptions made at the CONNACK
        self.subscriptions: dict[int, str] = {}
        self.v5 = fw.cfg.protocol == "5"
        #: a persistent session whose commands are acknowledged once answered
        self.persistent = self.v5 and bool(fw.set_topics) and fw.cfg.profile != "sparkplug"
        if self.v5:  # a clean start is the argument of connect() in MQTT 5
            self.client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=client_id,
                                      protocol=mqtt.MQTTv5, manual_ack=self.persistent)
        else:
            self.client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=client_id,
                                      clean_session=True, protocol=mqtt.MQTTv311)
        self.client.max_inflight_messages_set(window + 20)
        self.client.max_queued_messages_set(0)
        c = self.client
        c.on_connect = self._on_connect
        c.on_disconnect = self._on_disconnect
        c.on_publish = self._on_publish
        c.on_subscribe = self._on_subscribe
        c.on_message = self._on_message
        c.on_log = self._on_log

    def connect_args(self) -> dict[str, Any]:
        """connect()'s session arguments: a persistent session resumed (MQTT 5)."""
        if not self.persistent:
            return {}
        from paho.mqtt.packettypes import PacketTypes
        from paho.mqtt.properties import Properties

        props = Properties(PacketTypes.CONNECT)  # type: ignore[no-untyped-call]
        props.SessionExpiryInterval = COMMAND_SESSION_EXPIRY
        return {"clean_start": False, "properties": props}

    def disconnect(self, *, end_session: bool) -> None:
        """DISCONNECT; ``end_session``: a persistent session ends with it (a clean
        stop: no command waits for this logger to come back)."""
        if self.persistent and end_session:
            from paho.mqtt.packettypes import PacketTypes
            from paho.mqtt.properties import Properties

            props = Properties(PacketTypes.DISCONNECT)  # type: ignore[no-untyped-call]
            props.SessionExpiryInterval = 0
            self.client.disconnect(properties=props)
        else:
            self.client.disconnect()

    def _ack(self, mid: int, qos: int) -> None:
        """Acknowledge a received message (a persistent session's, by hand); on
        a lost connection the broker delivers it again on the next."""
        if self.persistent and not self.lost:
            with contextlib.suppress(Exception):
                self.client.ack(mid, qos)

    def _on_connect(self, client: Any, userdata: Any, flags: Any, rc: Any,
                    props: Any = None) -> None:
        self.ok = not rc.is_failure
        self.reason = None if self.ok else \
            f"refused: {rc}{self.fw.cfg.credentials_words(rc.value)}"
        if self.v5 and rc.value == 0x84:  # a broker of MQTT 3.1.1 only
            self.reason = (f"refused: {rc} (MQTT 5); a broker of MQTT 3.1.1 only needs "
                           "--mqtt-protocol 3.1.1")
        if self.ok and self.fw.profile.command_topic:
            self._subscribe(client, self.fw.profile.command_topic)
        if self.ok and self.fw.profile.host_topic:
            self._subscribe(client, self.fw.profile.host_topic)
        if self.ok and self.fw.set_topics:
            # a command's result goes out at once, not after the ACK of the
            # samples in flight (Nagle): the write commands' latency
            sock: Any = client.socket()
            with contextlib.suppress(OSError, AttributeError):
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            for topic in self.fw.set_topics:
                self._subscribe(client, topic)
        self.connack.set()

    def _subscribe(self, client: Any, topic: str) -> None:
        """SUBSCRIBE (QoS 1), its message id remembered to tell a refusal."""
        _rc, mid = client.subscribe(topic, qos=1)
        if mid is not None:
            self.subscriptions[mid] = topic

    def _on_disconnect(self, client: Any, userdata: Any, flags: Any, rc: Any,
                       props: Any = None) -> None:
        self.lost = True
        if self.reason is None:
            code = getattr(rc, "value", rc)
            from_server = bool(getattr(flags, "is_disconnect_packet_from_server", False))
            self.ended_by_broker = from_server or code != 0
            self.taken_over = from_server and code == TAKEN_OVER
            self.reason = f"disconnected: {rc}"
        self.connack.set()
        self.fw.wake.set()

    def _on_publish(self, client: Any, userdata: Any, mid: int, rc: Any, props: Any) -> None:
        # MQTT 5: a PUBACK's reason code of 0x80 or more is the broker's no
        refused = str(rc) if rc is not None and getattr(rc, "is_failure", False) else None
        self.acks.append((mid, refused))
        self.fw.wake.set()

    def _on_subscribe(self, client: Any, userdata: Any, mid: int, rcs: Any, props: Any) -> None:
        topic = self.subscriptions.pop(mid, None)
        refused = [rc for rc in rcs or () if getattr(rc, "is_failure", False)]
        if topic is not None and refused:  # an ACL that denies it, say
            self.fw.subscription_refused(topic, str(refused[0]))
        self.acks.append((mid, None))
        self.fw.wake.set()

    def _on_log(self, client: Any, userdata: Any, level: int, buf: str) -> None:
        if buf.startswith("Received malformed packet") and self.reason is None:
            # mosquitto 2.0 answers a message over its message_size_limit with a
            # PUBACK whose reason (0x95) MQTT 5 does not allow there; paho drops
            # the connection
            self.reason = ("the broker sent a packet paho cannot read (mosquitto 2.0 does "
                           "for a message over its message_size_limit)")

    def _on_message(self, client: Any, userdata: Any, msg: Any) -> None:
        if msg.topic in self.fw.set_topics:
            # (MQTT 5: the retain flag is set only on what a new subscription brings)
            retained = bool(msg.retain)
            if self.persistent:
                mid, qos = msg.mid, msg.qos
                self.fw.command_arrived(msg.topic, msg.payload, lambda: self._ack(mid, qos),
                                        retained=retained)
            else:
                self.fw.command_arrived(msg.topic, msg.payload, retained=retained)
            return
        self._ack(msg.mid, msg.qos)  # a topic of an earlier run's session, say
        if msg.topic == self.fw.profile.command_topic and self.fw.profile.command(msg.payload):
            self.fw.rebirth.set()
            self.fw.wake.set()
        elif msg.topic == self.fw.profile.host_topic:
            self._host_state(msg.payload)

    def _host_state(self, payload: bytes) -> None:
        """The primary host's STATE (Sparkplug 3.0: online only with a timestamp >=
        the previous STATE's; offline only with one >= the last online's)."""
        fw = self.fw
        state = host_state(payload)
        if state is None:
            fw.record_event(f"ignored a STATE of the primary host that is not Sparkplug 3.0 JSON: "
                      f"{bytes(payload[:80])!r}")
            return
        online, ts = state
        if online and (fw.host_ts is None or ts >= fw.host_ts):
            fw.host_ts = fw.host_online_ts = ts
            if not self.host_online:
                fw.record_event(f"the primary host {fw.cfg.primary_host} is online")
            self.host_online = True
        elif not online and (fw.host_online_ts is None or ts >= fw.host_online_ts):
            fw.host_ts = max(ts, fw.host_ts or ts)
            if self.host_online:
                fw.record_event(f"the primary host {fw.cfg.primary_host} is offline")
            self.host_online = False
        fw.wake.set()
