"""What goes on the wire: topics and payloads of the two profiles.

``plain``
    one JSON message per sample at QoS 1 on ``{prefix}/{node}/{device}``;
    a retained ``{prefix}/{node}/status`` says ``online``, the will
    ``offline``. Acknowledged by PUBACK.
``sparkplug``
    Sparkplug B 3.0: ``spBv1.0/{group}/{type}/{node}[/{device}]``, protobuf
    ``Payload`` messages. NDEATH (with the connection's ``bdSeq``) is the
    will, at QoS 1; NBIRTH (``seq`` 0, the same ``bdSeq``,
    ``Node Control/Rebirth``) then one DBIRTH per device with every metric,
    named and aliased; DDATA by alias, at QoS 0 as the specification
    requires, ``is_historical`` for the backlog replayed after an outage.
    Each DDATA carries the sample's id as the metric ``sample``. A device
    that stops answering (:mod:`pymb.fleet.health`) gets a DDEATH after its
    last DDATA, and a new DBIRTH before the DDATA of its next live sample.
    The node's metric ``Forwarder/Backlog`` (samples not yet acknowledged by
    the broker) is in NBIRTH and, when it changed, in an NDATA at most every
    5 s. QoS 0 has no
    acknowledgement: the forwarder follows each batch with a SUBSCRIBE of the
    node's NCMD topic and takes the broker's SUBACK (sent after it has
    handled everything before it on the connection) as the acknowledgement.
"""

from __future__ import annotations

import abc
import json
import re
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

from pymb.devices.readings import INTEGRAL_QUANTITIES, has_own_view, map_reading
from pymb.fleet.config import MqttConfig
from pymb.fleet.mapmetrics import map_metadata, map_metrics, plain_value, point_properties
from pymb.fleet.protobuf import (
    DataType,
    Metric,
    MetricValue,
    Properties,
    command_metrics,
    encode_payload,
)
from pymb.maps import Point
from pymb.store import Outbox, StoredSample, sample_dict
from pymb.store.records import reading_values

__all__ = ["Message", "PlainProfile", "Profile", "SparkplugProfile", "host_state",
           "make_profile", "state_payload", "write_name"]

NAMESPACE = "spBv1.0"
REBIRTH = "Node Control/Rebirth"
BDSEQ = "bdSeq"
BACKLOG = "Forwarder/Backlog"
#: the node's metrics besides bdSeq: name -> (alias, datatype); in NBIRTH, then NDATA
NODE_METRICS = {REBIRTH: (1, DataType.BOOLEAN), BACKLOG: (2, DataType.UINT64)}
NDATA_EVERY = 5.0  #: seconds: a changed node metric goes in an NDATA at most this often
QUALITY_BAD = 0  #: Sparkplug 3.0's "Quality" property: 0 bad, 192 good
_CHANNEL = re.compile(r"channel 0*(\d+)/(.+)")  #: a block channel's metric


@dataclass(frozen=True)
class Message:
    """One MQTT publication."""

    topic: str
    payload: bytes
    qos: int
    retain: bool = False


def _ms(t: float) -> int:
    return round(t * 1000)


class Profile(abc.ABC):
    """The interface the forwarder drives."""

    data_qos = 1
    command_topic: str | None = None
    host_topic: str | None = None  #: the primary host application's STATE topic, if any

    def __init__(self, cfg: MqttConfig) -> None:
        self.cfg = cfg

    @abc.abstractmethod
    def will(self) -> Message:
        """The last will, registered with each CONNECT."""

    @abc.abstractmethod
    def births(self, source: Outbox, node: dict[str, int] | None = None) -> list[Message]:
        """What goes first on every connection (and on a rebirth); ``node``: the
        node's metrics (``NODE_METRICS``) now."""

    @abc.abstractmethod
    def data(self, record: StoredSample, historical: bool) -> list[Message]:
        """The message(s) of one sample."""

    @abc.abstractmethod
    def goodbye(self) -> list[Message]:
        """What goes last on a clean disconnect."""

    def missed(self, topic: str) -> str:
        """What this node misses while the broker refuses it ``topic``'s subscription."""
        if topic == self.host_topic:
            return (f"the primary host's STATE cannot reach this node, which publishes "
                    f"nothing until the broker lets it read {topic}")
        if topic == self.command_topic:
            return "Rebirth commands (NCMD) cannot reach this node"
        return "write commands on it cannot reach this logger"

    def device_down(self, device: str) -> list[Message]:
        """A device stopped answering (see :mod:`pymb.fleet.health`)."""
        return []

    def node_data(self, values: dict[str, int]) -> list[Message]:
        """The node's own metrics (``NODE_METRICS``), when they changed."""
        return []

    def command(self, payload: bytes) -> bool:
        """True when a command received asks for new births."""
        return False

    def command_data(self, device: str, values: Mapping[str, MetricValue], names: Sequence[str],
                     latest: StoredSample | None) -> list[Message]:
        """What answers a device command (Sparkplug: a DDATA)."""
        return []

    def new_connection(self, source: Outbox) -> None:  # noqa: B027 (a no-op by default)
        """Called before each CONNECT."""


class PlainProfile(Profile):
    """JSON at QoS 1; a retained status topic."""

    def __init__(self, cfg: MqttConfig) -> None:
        super().__init__(cfg)
        self.base = f"{cfg.prefix}/{cfg.node}"
        self.meta_sent: set[str] = set()  #: map devices whose metadata went out

    def will(self) -> Message:
        """``offline``, retained."""
        return Message(f"{self.base}/status", b"offline", 1, True)

    def births(self, source: Outbox, node: dict[str, int] | None = None) -> list[Message]:
        """``online``, retained; and for each map device, its retained
        ``{device}/meta`` (units and kinds of its points)."""
        out = [Message(f"{self.base}/status", b"online", 1, True)]
        for name, _type, _address in source.devices():
            latest = source.latest(name)
            if latest is not None and not has_own_view(latest.data):
                self.meta_sent.add(name)
                meta = map_metadata(map_reading(latest.data).map)
                out.append(Message(f"{self.base}/{name}/meta", meta, 1, True))
        return out

    def data(self, record: StoredSample, historical: bool) -> list[Message]:
        """The sample as one JSON object (a map device's metadata first, if
        it came after the births)."""
        body = json.dumps(sample_dict(record), allow_nan=False, separators=(",", ":"))
        name = record.device.name
        out = []
        if not has_own_view(record.data) and name not in self.meta_sent:
            self.meta_sent.add(name)
            meta = map_metadata(map_reading(record.data).map)
            out.append(Message(f"{self.base}/{name}/meta", meta, 1, True))
        out.append(Message(f"{self.base}/{name}", body.encode(), 1))
        return out

    def goodbye(self) -> list[Message]:
        """``offline``, retained (the will is not sent on a clean disconnect)."""
        return [self.will()]


@dataclass
class _Birth:
    """The metrics a DBIRTH declared for one device: name -> alias."""

    aliases: dict[str, int]
    channels: int


class SparkplugProfile(Profile):
    """Sparkplug B 3.0, one edge node with one Sparkplug device per pymb device."""

    data_qos = 0

    def __init__(self, cfg: MqttConfig) -> None:
        super().__init__(cfg)
        g, n = cfg.group, cfg.node
        self.node_topic = f"{NAMESPACE}/{g}/{{}}/{n}"
        self.command_topic = f"{NAMESPACE}/{g}/NCMD/{n}"
        if cfg.primary_host:
            self.host_topic = f"{NAMESPACE}/STATE/{cfg.primary_host}"
        self.state_key = f"sparkplug:{g}/{n}:bdSeq"
        self.bd_seq = 0
        self.seq = 0
        self.born: dict[str, _Birth] = {}
        self.device_order: dict[str, int] = {}
        #: devices that stopped answering; their DDEATH was (or, unborn, need not be) sent
        self.down: set[str] = set()
        self.node_values: dict[str, int] = {}  #: as last published (NBIRTH or NDATA)
        self.node_sent = 0.0  #: time.monotonic() of that
        #: (device, point) -> whether a DCMD may write it: its DBIRTH metric says
        #: ``writable`` (set by the logger that takes write commands)
        self.writable: Callable[[str, str], bool] = lambda device, point: False

    def birth_aliases(self, device: str) -> dict[str, int] | None:
        """The metrics (name -> alias) of ``device``'s last DBIRTH of this
        session; None before it (any thread)."""
        birth = self.born.get(device)
        return None if birth is None else birth.aliases

    def command_data(self, device: str, values: Mapping[str, MetricValue], names: Sequence[str],
                     latest: StoredSample | None) -> list[Message]:
        """The DDATA that answers a DCMD: each metric of ``names`` with its value
        in ``values`` (read back after the write), else its current value (the
        device's latest sample); nothing while the device is not born."""
        birth = self.born.get(device)
        if birth is None or latest is None or has_own_view(latest.data):
            return []
        now = _ms(time.time())
        current = {name: (dt, v, st)
                   for name, dt, v, st, _ in map_metrics(map_reading(latest.data), True)}
        metrics = []
        for name in dict.fromkeys(names):
            if name not in current or name not in birth.aliases:
                continue
            dt, v, st = current[name]
            if name in values:
                v, st = values[name], "value"
            metrics.append(Metric(None, birth.aliases[name], dt, v, now, False,
                                  self._props(st)))
        if not metrics:
            return []
        payload = encode_payload(metrics, timestamp=now, seq=self._next_seq())
        return [Message(self.node_topic.format("DDATA") + f"/{device}", payload, 0)]

    def _next_seq(self) -> int:
        s = self.seq
        self.seq = (s + 1) % 256
        return s

    def new_connection(self, source: Outbox) -> None:
        """A new bdSeq (0..255, counting across restarts), remembered durably
        before the CONNECT that registers it in the will."""
        last = source.state(self.state_key)
        self.bd_seq = 0 if last is None else (last + 1) % 256
        source.set_state(self.state_key, self.bd_seq)

    def _bd_metric(self) -> Metric:
        # Sparkplug 3.0: "a metric with the name of 'bdSeq', the datatype of INT64"
        return Metric(BDSEQ, None, DataType.INT64, self.bd_seq, _ms(time.time()))

    def will(self) -> Message:
        """NDEATH with this connection's bdSeq, QoS 1, not retained."""
        payload = encode_payload([self._bd_metric()], timestamp=_ms(time.time()))
        return Message(self.node_topic.format("NDEATH"), payload, 1, False)

    def births(self, source: Outbox, node: dict[str, int] | None = None) -> list[Message]:
        """NBIRTH (seq 0, with the node's metrics) and a DBIRTH for each device that
        has samples, with its newest values; then a DDEATH for each device that is
        down (its metrics declared, for the backlog's historical DDATA)."""
        now = _ms(time.time())
        self.seq = 0
        self.born.clear()
        self.node_values = dict(node or {BACKLOG: 0})
        self.node_sent = time.monotonic()
        metrics = [self._bd_metric(), Metric(REBIRTH, 1, DataType.BOOLEAN, False, now)]
        metrics += [Metric(name, NODE_METRICS[name][0], NODE_METRICS[name][1], value, now)
                    for name, value in self.node_values.items()]
        nbirth = encode_payload(metrics, timestamp=now, seq=self._next_seq())
        out = [Message(self.node_topic.format("NBIRTH"), nbirth, 0)]
        dead = []
        for name, _type, _address in source.devices():
            self._order(name)
            latest = source.latest(name)
            if latest is not None:
                out.append(self._dbirth(latest))
                if name in self.down:
                    dead.append(name)
        out += [self._ddeath(name) for name in dead]
        return out

    def _ddeath(self, device: str) -> Message:
        """DDEATH: the payload's timestamp (now) and seq, no metrics; QoS 0."""
        payload = encode_payload([], timestamp=_ms(time.time()), seq=self._next_seq())
        return Message(self.node_topic.format("DDEATH") + f"/{device}", payload, 0)

    def device_down(self, device: str) -> list[Message]:
        """A DDEATH if the device was born in this session and is not down yet."""
        if device in self.down:
            return []
        self.down.add(device)
        return [self._ddeath(device)] if device in self.born else []

    def node_data(self, values: dict[str, int]) -> list[Message]:
        """An NDATA (by alias) of the node metrics that changed since the last
        NBIRTH or NDATA, at most every NDATA_EVERY seconds."""
        changed = {k: v for k, v in values.items() if self.node_values.get(k) != v}
        if not changed or time.monotonic() - self.node_sent < NDATA_EVERY:
            return []
        now = _ms(time.time())
        self.node_values.update(changed)
        self.node_sent = time.monotonic()
        payload = encode_payload(
            [Metric(None, NODE_METRICS[k][0], NODE_METRICS[k][1], v, now)
             for k, v in changed.items()], timestamp=now, seq=self._next_seq())
        return [Message(self.node_topic.format("NDATA"), payload, 0)]

    def _order(self, device: str) -> int:
        return self.device_order.setdefault(device, len(self.device_order) + 1)

    def _metrics(self, r: StoredSample, birth: bool = False
                 ) -> list[tuple[str, DataType, MetricValue, str, Properties]]:
        """(name, datatype, value, state, birth properties) of every metric of
        a sample (a hub's channel by channel, as
        :func:`pymb.store.records.reading_values` gives them, None for no
        value; a map device's in a birth: every point of its map)."""
        out: list[tuple[str, DataType, MetricValue, str, Properties]] = [
            ("sample", DataType.UINT64, r.id, "value", ())]
        if not has_own_view(r.data):
            out += [(name, dt, v, st, self._birth_props(r.device.name, name, p) if birth else ())
                    for name, dt, v, st, p in map_metrics(map_reading(r.data), birth)]
            return out
        for ch, q, v, st in reading_values(r.data, not_read=True):
            dt = DataType.DOUBLE if q not in INTEGRAL_QUANTITIES else (
                DataType.UINT32 if q == "status" else DataType.UINT64)
            out.append((q if ch is None else f"channel {ch:03d}/{q}", dt,
                        plain_value(v), str(st), ()))
        return out

    def _birth_props(self, device: str, metric: str, p: Point
                     ) -> Properties:
        """A point's birth properties, and ``writable`` (true) where a DCMD may write it."""
        props = point_properties(p)
        if p.writable and self.writable(device, write_name(metric)):
            props += (("writable", DataType.BOOLEAN, 1),)
        return props

    @staticmethod
    def _props(state: str) -> Properties:
        if state == "value":
            return ()
        return (("Quality", DataType.INT32, QUALITY_BAD), ("state", DataType.STRING, state))

    def _dbirth(self, r: StoredSample) -> Message:
        device = r.device.name
        base = self._order(device) * 100000
        t = _ms(r.time_utc)
        metrics, aliases = [], {}
        for i, (name, dt, value, state, props) in enumerate(self._metrics(r, True)):
            aliases[name] = base + i
            metrics.append(Metric(name, base + i, dt, value, t, False,
                                  props + self._props(state)))
        self.born[device] = _Birth(aliases, _channels(r))
        payload = encode_payload(metrics, timestamp=_ms(time.time()), seq=self._next_seq())
        return Message(self.node_topic.format("DBIRTH") + f"/{device}", payload, 0)

    def data(self, record: StoredSample, historical: bool) -> list[Message]:
        """DDATA by alias; a DBIRTH first for a device not yet born and for a
        device that was down and answers again (a live sample). The backlog of a
        device that is down goes as historical DDATA and leaves it down."""
        out = []
        device = record.device.name
        birth = self.born.get(device)
        down = device in self.down
        if birth is None or birth.channels != _channels(record) or (down and not historical):
            out.append(self._dbirth(record))
            birth = self.born[device]
            if down and historical:
                out.append(self._ddeath(device))
            else:
                self.down.discard(device)
        t = _ms(record.time_utc)
        metrics = [Metric(None, birth.aliases[name], dt, value, t, historical, self._props(st))
                   for name, dt, value, st, _ in self._metrics(record)]
        payload = encode_payload(metrics, timestamp=_ms(time.time()), seq=self._next_seq())
        out.append(Message(self.node_topic.format("DDATA") + f"/{device}", payload, 0))
        return out

    def goodbye(self) -> list[Message]:
        """NDEATH, as the will would say it."""
        return [self.will()]

    def command(self, payload: bytes) -> bool:
        """True for ``Node Control/Rebirth`` = true (by name or its alias)."""
        try:
            metrics = command_metrics(payload)
        except (ValueError, UnicodeDecodeError):
            return False
        return any((name == REBIRTH or (name is None and alias == 1)) and value
                   for name, alias, value in metrics)


def write_name(metric: str) -> str:
    """The point name of a metric (a write's, a row's of ``pymb collect``):
    ``channel 003/x`` is ``x_3``."""
    m = _CHANNEL.fullmatch(metric)
    return f"{m.group(2)}_{int(m.group(1))}" if m else metric


def _channels(r: StoredSample) -> int:
    """A hub sample's channels (0 for the others): a new count needs a new DBIRTH."""
    b = map_reading(r.data).blocks
    return 0 if b is None else b.channels


def state_payload(online: bool, timestamp_ms: int) -> bytes:
    """A Sparkplug 3.0 STATE payload (what :func:`host_state` reads)."""
    return json.dumps({"online": online, "timestamp": timestamp_ms},
                      separators=(",", ":")).encode()


def host_state(payload: bytes) -> tuple[bool, float] | None:
    """(online, timestamp in ms) of a Sparkplug 3.0 STATE message (UTF-8 JSON
    ``{"online": true|false, "timestamp": ms}``); None when it is not one."""
    try:
        doc = json.loads(payload.decode("utf-8"))
    except (UnicodeDecodeError, ValueError):
        return None
    if not isinstance(doc, dict):
        return None
    online, ts = doc.get("online"), doc.get("timestamp")
    if not isinstance(online, bool) or isinstance(ts, bool) or not isinstance(ts, int | float):
        return None
    return online, float(ts)


def make_profile(cfg: MqttConfig) -> Profile:
    """The profile the configuration names."""
    return SparkplugProfile(cfg) if cfg.profile == "sparkplug" else PlainProfile(cfg)
