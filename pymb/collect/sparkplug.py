"""The Sparkplug B profile of the collector: a host application.

It reads ``spBv1.0/{group}/#``: births (NBIRTH, DBIRTH) declare each metric's
name, alias and datatype, data (NDATA, DDATA) name them by alias or by name,
without the datatype (Sparkplug 3.0: it should not be repeated).
Every message but NDEATH carries a ``seq`` (0..255, wrapping) per edge node;
on a gap, or on data from a node or device it has no birth for (none yet, or
none since the node's NDEATH), the host asks the node for new births with an
NCMD ``Node Control/Rebirth`` (at most once per node every
:data:`REBIRTH_EVERY` seconds); a DDEATH leaves the device's DBIRTH in force.
Its own state goes on ``spBv1.0/STATE/{host_id}`` (retained; the will says
offline).

Rows: ``node`` is the edge node, ``device`` the device (``""`` for the node's
own metrics), ``point`` the metric's name (pymb's ``channel NNN/NAME`` as
``NAME_N``, as in the plain profile); ``bdSeq`` and ``Node Control/*`` are
not stored, nor metrics of the kinds that are no single value (DataSet,
Template, Bytes, File).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

from pymb.collect.rows import NO_VALUE, BadInput, Row
from pymb.fleet.profiles import NAMESPACE, REBIRTH, state_payload, write_name
from pymb.fleet.protobuf import (
    TEXTS,
    DataType,
    FieldError,
    Fields,
    Metric,
    decode,
    encode_payload,
    last,
    metric_fields,
    metric_value,
    number,
    text,
)

__all__ = ["REBIRTH_EVERY", "SparkplugHost", "state_payload"]  # state_payload: fleet.profiles' own

REBIRTH_EVERY = 5.0  #: seconds: a node is asked for births at most this often
_KINDS = ("NBIRTH", "NDEATH", "NDATA", "DBIRTH", "DDEATH", "DDATA", "NCMD", "DCMD")
#: datatypes with no single value (DataSet, Bytes, File, Template)
_SKIPPED = {16, 17, 18, 19}


@dataclass
class _Born:
    """The metrics one birth (an NBIRTH, a DBIRTH) declared."""

    aliases: dict[int, tuple[str, int]] = field(default_factory=dict)  #: alias: (name, datatype)
    types: dict[str, int] = field(default_factory=dict)  #: name: datatype
    #: alias: two names the birth gave it (Sparkplug: an alias names one metric)
    twice: dict[int, tuple[str, str]] = field(default_factory=dict)


@dataclass
class _Node:
    """What the host knows of one edge node (since its last NBIRTH)."""

    born: bool = False
    bd_seq: int | None = None
    seq: int | None = None
    metrics: _Born = field(default_factory=_Born)  #: the node's own
    devices: dict[str, _Born] = field(default_factory=dict)
    asked: float = float("-inf")  #: time.monotonic() of the last rebirth request


def _state_property(raw: bytes) -> str | None:
    """The ``state`` property of a metric's PropertySet, if any."""
    props = decode(raw)
    keys = [k.decode(errors="replace") for k in props.get(1, []) if isinstance(k, bytes)]
    values = [v for v in props.get(2, []) if isinstance(v, bytes)]
    for k, v in zip(keys, values, strict=False):
        if k == "state":
            return text(decode(v), 8)
    return None


class SparkplugHost:
    """The host application's view of every edge node of one group.

    ``send(topic, payload)`` publishes (QoS 0) a rebirth request; ``event`` reports
    what happened (a seq gap, an unknown birth)."""

    def __init__(self, group: str, host_id: str, send: Callable[[str, bytes], None],
                 event: Callable[[str], None]) -> None:
        self.group = group
        self.host_id = host_id
        self.state_topic = f"{NAMESPACE}/STATE/{host_id}"
        self.subscription = f"{NAMESPACE}/{group}/#"
        self.send = send
        self.event = event
        self.nodes: dict[str, _Node] = {}
        self.rebirths = 0  #: rebirth requests sent
        self.unborn = 0  #: messages dropped for want of a birth

    def _rebirth(self, node: str, st: _Node, why: str) -> None:
        now = time.monotonic()
        if now - st.asked < REBIRTH_EVERY:
            return
        st.asked = now
        self.rebirths += 1
        ms = round(time.time() * 1000)
        payload = encode_payload([Metric(REBIRTH, None, DataType.BOOLEAN, True, ms)],
                                 timestamp=ms)
        self.send(f"{NAMESPACE}/{self.group}/NCMD/{node}", payload)
        self.event(f"asked {self.group}/{node} for a rebirth: {why}")

    def rows(self, topic: str, payload: bytes) -> list[Row]:
        """The rows of one message (none for births' bookkeeping, deaths and
        commands). Raises BadInput for a topic or payload of no known shape."""
        parts = topic.split("/")
        if (len(parts) not in (4, 5) or parts[0] != NAMESPACE or parts[1] != self.group
                or parts[2] not in _KINDS or not all(parts[3:])):
            raise BadInput("not a Sparkplug B topic spBv1.0/{group}/{type}/{node}[/{device}]")
        kind, node = parts[2], parts[3]
        device = parts[4] if len(parts) == 5 else None
        if (device is None) != (kind[0] == "N"):
            raise BadInput(f"a {kind} topic with the wrong number of levels")
        if kind in ("NCMD", "DCMD"):
            return []
        try:
            p = decode(payload)
            metrics = metric_fields(p)
        except ValueError as e:
            raise BadInput(f"not a Sparkplug B payload ({e})") from None
        try:
            return self._rows(kind, node, device, p, metrics)
        except FieldError as e:  # a field of the wrong kind
            raise BadInput(str(e)) from None

    def _rows(self, kind: str, node: str, device: str | None, p: Fields,
              metrics: list[Fields]) -> list[Row]:
        """:meth:`rows` of a decoded payload (FieldError for a field of the wrong kind)."""
        ms = number(p, 1)
        seq = number(p, 3)
        st = self.nodes.setdefault(node, _Node())
        if kind == "NDEATH":
            return self._death(node, st, metrics)
        if seq is None or seq > 255:
            raise BadInput(f"a {kind} without a seq of 0..255")
        if kind == "NBIRTH":
            st.born, st.seq, st.metrics, st.devices = True, seq, _Born(), {}
            for m in metrics:
                if text(m, 1) == "bdSeq":
                    st.bd_seq = number(m, 11)
        elif not st.born:
            self.unborn += 1
            self._rebirth(node, st, f"{kind} before its NBIRTH")
            return []
        else:
            expected = ((st.seq or 0) + 1) % 256 if st.seq is not None else seq
            st.seq = seq
            if seq != expected:
                self._rebirth(node, st, f"seq {seq} after {(expected - 1) % 256}")
        if kind == "DBIRTH":
            assert device is not None
            st.devices[device] = _Born()
        if kind == "DDEATH":  # its aliases stay: a board's backlog of it may follow
            return []
        if device is not None and device not in st.devices:
            self.unborn += 1
            self._rebirth(node, st, f"{kind} of {device}, which has no DBIRTH")
            return []
        born = st.metrics if device is None else st.devices[device]
        t0 = ms / 1000 if ms is not None else time.time()
        out: list[Row] = []
        for m in metrics:
            try:
                row = self._metric(node, device or "", m, born, t0, kind.endswith("BIRTH"))
            except (BadInput, FieldError):
                raise
            except (ValueError, OverflowError) as e:  # a PropertySet, a float's field
                raise BadInput(f"not a Sparkplug B payload (a metric: {e})") from None
            if row is None and not kind.endswith("BIRTH"):
                self.unborn += 1
                what = f"a metric {text(m, 1)!r}" if text(m, 1) is not None else "an alias"
                self._rebirth(node, st, f"{kind} with {what} no birth declared")
                return []
            if row is not None and row[2]:
                out.append(row)
        for alias, (a, b) in born.twice.items():  # (a birth's, so said once a birth)
            born.aliases.pop(alias, None)
            where = f"{node}/{device}" if device is not None else node
            self.event(f"the {kind} of {self.group}/{where} gives alias {alias} to {a!r} and "
                       f"{b!r}: data naming that alias are not stored")
        return out

    def _death(self, node: str, st: _Node, metrics: list[Fields]
               ) -> list[Row]:
        bd = next((number(m, 11) for m in metrics if text(m, 1) == "bdSeq"), None)
        if st.born and (bd is None or st.bd_seq is None or bd == st.bd_seq):
            st.born = False
            self.event(f"{self.group}/{node} is offline (NDEATH)")
        return []

    def _metric(self, node: str, device: str, m: Fields, born: _Born, t0: float,
                birth: bool) -> Row | None:
        """The row of one metric; None for data the births do not declare (an
        alias, or a name without a datatype: Sparkplug's data name a metric by
        alias or name and should not repeat its datatype). A row with an empty
        point is a metric that is not stored (bdSeq, Node Control/*)."""
        name = text(m, 1)
        alias = number(m, 2)
        datatype = number(m, 4)
        if name is None:
            if alias in born.twice:
                raise BadInput(f"alias {alias} names two metrics of the birth "
                               f"({born.twice[alias][0]!r}, {born.twice[alias][1]!r})")
            if alias is None or alias not in born.aliases:
                return None
            name, declared = born.aliases[alias]
            datatype = datatype if datatype is not None else declared
        elif datatype is None and not birth:
            datatype = born.types.get(name)
            if datatype is None:
                return None
        if datatype is None:
            raise BadInput(f"metric {name!r} has no datatype")
        if birth:
            born.types[name] = datatype
            if alias is not None:
                had = born.aliases.get(alias)
                if had is not None and had[0] != name:
                    born.twice[alias] = (had[0], name)
                born.aliases[alias] = (name, datatype)
        if name == "bdSeq" or name.startswith("Node Control/") or datatype in _SKIPPED:
            return (node, device, "", t0, None, None, None, None)
        ts = number(m, 3)
        t = ts / 1000 if ts is not None else t0
        point = write_name(name)
        if number(m, 7):  # is_null
            props = last(m, 9)
            why = _state_property(props) if isinstance(props, bytes) else None
            return (node, device, point, t, None, None, why or NO_VALUE, None)
        v = metric_value(m, datatype)
        if v is None and datatype not in TEXTS:
            raise BadInput(f"a metric of datatype {datatype} has no value")
        if isinstance(v, str):
            return (node, device, point, t, None, v, None, None)
        if v is None or v != v or v in (float("inf"), float("-inf")):
            return (node, device, point, t, None, None, NO_VALUE, None)
        return (node, device, point, t, float(v), None, None, None)
