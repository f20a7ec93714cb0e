"""A stored row of ``pymb_values`` and what the plain profile's JSON becomes.

A :data:`Row` is ``(node, device, point, time, value, text, state, sample)``;
the store adds ``received``. Input that does not have the shape of a pymb
sample raises :class:`BadInput`, whose message says why; the collector
counts it and goes on.
"""

from __future__ import annotations

import json
import math
from typing import Any

__all__ = ["NO_VALUE", "BadInput", "Row", "channel_point", "plain_rows", "plain_topic"]

#: (node, device, point, time [Unix s], value, text, state, sample)
Row = tuple[str, str, str, float, float | None, str | None, str | None, int | None]

#: the state of a point that has no value and no reason given
NO_VALUE = "no_value"

#: the last level of a plain topic that is not a device's samples
_NOT_SAMPLES = ("status", "set")


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
    if parts[2] in _NOT_SAMPLES:
        return None
    return parts[1], parts[2]


def _number(v: Any) -> float | None:
    """A finite number (booleans as 0/1); None when ``v`` is not one."""
    if isinstance(v, bool):
        return 1.0 if v else 0.0
    if isinstance(v, int | float):
        f = float(v)
        return f if math.isfinite(f) else None
    return None


def _state(v: Any, where: str) -> str | None:
    if v is None or isinstance(v, str):
        return v
    raise BadInput(f"the state of {where} is not a string: {v!r:.40}")


def _one(node: str, device: str, point: str, t: float, v: Any, state: Any,
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


def plain_rows(node: str, device: str, payload: bytes) -> list[Row]:
    """The rows of one plain-profile message (a sample of ``pymb log --mqtt``):
    one per value of ``values``, a block's channel N as ``name_N``; ``states``
    says why a value is null. Raises BadInput when it is not such a message."""
    try:
        doc = json.loads(payload)
    except (UnicodeDecodeError, ValueError) as e:
        raise BadInput(f"not JSON ({e})") from None
    if not isinstance(doc, dict):
        raise BadInput("not a JSON object")
    t = _number(doc.get("time_utc"))
    if t is None or isinstance(doc.get("time_utc"), bool):
        raise BadInput("no time_utc (Unix seconds)")
    sample = doc.get("sample")
    if sample is not None and (isinstance(sample, bool) or not isinstance(sample, int)):
        raise BadInput(f"sample is not an integer: {sample!r:.40}")
    values = doc.get("values")
    if not isinstance(values, dict):
        raise BadInput("no values object")
    states = doc.get("states") or {}
    if not isinstance(states, dict):
        raise BadInput("states is not an object")
    rows: list[Row] = []
    for name, v in values.items():
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
