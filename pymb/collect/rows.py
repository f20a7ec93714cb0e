"""A stored row of ``pymb_values`` and what the plain profile's JSON becomes.

A :data:`Row` is ``(node, device, point, time, value, text, state, sample)``;
the store adds ``received``. Input that does not have the shape of a pymb
sample raises :class:`BadInput`, whose message says why; the collector
counts it and goes on.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence
from typing import NamedTuple, Protocol

from pymb.fleet.config import NODE_TOPICS
from pymb.jsonvalue import JsonValue

__all__ = ["NO_VALUE", "BadInput", "Batch", "PlainSample", "Row", "RowBatch", "channel_point",
           "plain_rows", "plain_sample", "plain_topic", "sample_rows"]

#: (node, device, point, time [Unix s], value, text, state, sample)
Row = tuple[str, str, str, float, float | None, str | None, str | None, int | None]

#: the state of a point that has no value and no reason given
NO_VALUE = "no_value"

_loads: Callable[[bytes], JsonValue]
try:  # in the extra collect; the json module decodes the same documents, 4x slower
    from orjson import loads as _loads
except ImportError:  # pragma: no cover - without the extra
    _loads = json.loads



class BadInput(ValueError):
    """A message that is not what the profile publishes (its reason as the text)."""


def channel_point(name: str, channel: int) -> str:
    """A block's point for channel ``channel`` (from 1): ``name_N``."""
    return f"{name}_{channel}"


def plain_topic(topic: str, prefix: str) -> tuple[str, str] | None:
    """(node, device) of a plain sample's topic ``{prefix}/{node}/{device}``;
    None for the topics that carry no samples (``status``, ``set``). Raises
    BadInput for a topic of another shape."""
    parts = topic.split("/")
    if len(parts) != 3 or parts[0] != prefix or not parts[1] or not parts[2]:
        raise BadInput("not a topic of the form {prefix}/{node}/{device}")
    if parts[2] in NODE_TOPICS:
        return None
    return parts[1], parts[2]


def _number(v: object) -> float | None:
    """A finite number (booleans as 0/1); None when ``v`` is not one."""
    if isinstance(v, bool):
        return 1.0 if v else 0.0
    if isinstance(v, int | float):
        try:
            f = float(v)
        except OverflowError:  # an integer beyond a double
            return None
        return f if math.isfinite(f) else None
    return None


def _state(v: object, where: str) -> str | None:
    if v is None or isinstance(v, str):
        return v
    raise BadInput(f"the state of {where} is not a string: {v!r:.40}")


def _one(node: str, device: str, point: str, t: float, v: object, state: object,
         sample: int | None) -> Row:
    if v is None:
        why = _state(state, point)
        return (node, device, point, t, None, None,
                why if why and why != "value" else NO_VALUE, sample)
    if isinstance(v, str):
        return (node, device, point, t, None, v, None, sample)
    f = _number(v)
    if f is None:
        raise BadInput(f"the value of {point} is not a number, boolean, string or null: "
                       f"{v!r:.40}")
    return (node, device, point, t, f, None, None, sample)


class PlainSample(NamedTuple):
    """One plain-profile message, its shape checked (not yet its values)."""

    time: float  #: time_utc, Unix seconds
    sample: int | None  #: the board's sample id
    values: dict[str, JsonValue]  #: name: a value, or a block's list of values
    states: dict[str, JsonValue]  #: name: why a value is null (a block's: a list)


def plain_sample(payload: bytes) -> PlainSample:
    """The parts of one plain-profile message (a sample of ``pymb log
    --mqtt``). Raises BadInput when it is not such a message."""
    try:
        doc = _loads(payload)
        strict = _loads is not json.loads  # orjson refuses a lone surrogate
    except ValueError:  # orjson refuses more (NaN, huge integers): the json module says
        try:
            doc = json.loads(payload)
        except (UnicodeDecodeError, ValueError, RecursionError) as e:  # (nested too deep)
            raise BadInput(f"not JSON ({e})") from None
        strict = False
    if not strict:  # the json module takes a lone surrogate, which no database stores
        try:
            json.dumps(doc, ensure_ascii=False).encode()
        except UnicodeEncodeError:
            raise BadInput("a text or name is not valid Unicode (a lone surrogate)") from None
    if not isinstance(doc, dict):
        raise BadInput("not a JSON object")
    t = _number(doc.get("time_utc"))
    if t is None or isinstance(doc.get("time_utc"), bool):
        raise BadInput("no time_utc (Unix seconds)")
    sample = doc.get("sample")
    if sample is not None and (isinstance(sample, bool) or not isinstance(sample, int)):
        raise BadInput(f"sample is not an integer: {sample!r:.40}")
    if sample is not None and not -(2**63) <= sample < 2**63:
        raise BadInput(f"sample {sample!r:.40} does not fit in 64 bits")
    values = doc.get("values")
    if not isinstance(values, dict):
        raise BadInput("no values object")
    states = doc.get("states") or {}
    if not isinstance(states, dict):
        raise BadInput("states is not an object")
    return PlainSample(t, sample, values, states)


def sample_rows(node: str, device: str, s: PlainSample) -> list[Row]:
    """The rows of a plain sample: one per value of ``values``, a block's
    channel N as ``name_N``; ``states`` says why a value is null. Raises
    BadInput for a value that is not a number, boolean, string or null."""
    t, sample, states = s.time, s.sample, s.states
    rows: list[Row] = []
    for name, v in s.values.items():
        st = states.get(name)
        if isinstance(v, list):
            if st is not None and not (isinstance(st, list) and len(st) == len(v)):
                raise BadInput(f"the states of {name} do not match its {len(v)} values")
            for i, x in enumerate(v):
                point = channel_point(name, i + 1)
                if isinstance(x, list | dict):
                    raise BadInput(f"the value of {point} is not a number, boolean, string "
                                   f"or null: {x!r:.40}")
                rows.append(_one(node, device, point, t, x, None if st is None else st[i],
                                 sample))
        else:
            rows.append(_one(node, device, name, t, v, st, sample))
    return rows


def plain_rows(node: str, device: str, payload: bytes) -> list[Row]:
    """The rows of one plain-profile message (:func:`plain_sample`, then
    :func:`sample_rows`). Raises BadInput when it is not such a message."""
    return sample_rows(node, device, plain_sample(payload))


class Batch(Protocol):
    """The rows of one transaction, as a store takes them. Adding a message
    that raises BadInput adds nothing of it."""

    rows: int  #: rows added
    newest: float | None  #: the newest time of a row added

    def add_plain(self, node: str, device: str, s: PlainSample) -> None:
        """The rows of one plain sample (BadInput for a value of no known kind)."""

    def add_rows(self, rows: Sequence[Row]) -> None:
        """Rows made elsewhere (the Sparkplug profile's)."""


class RowBatch:
    """A batch as a list of :data:`Row` tuples (SQLite binds them one by one)."""

    def __init__(self) -> None:
        self.items: list[Row] = []
        self.rows = 0
        self.newest: float | None = None

    def add_plain(self, node: str, device: str, s: PlainSample) -> None:
        """The rows of one plain sample (:func:`sample_rows`)."""
        self.add_rows(sample_rows(node, device, s))

    def add_rows(self, rows: Sequence[Row]) -> None:
        """Rows made elsewhere."""
        if rows:
            self.items.extend(rows)
            self.rows += len(rows)
            t = max(r[3] for r in rows)
            self.newest = t if self.newest is None or t > self.newest else self.newest
