"""JSON as pymb holds it: :data:`JsonValue`, what :func:`json.loads` gives and
:func:`json.dumps` takes, and :data:`JsonObject`, an object being built."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any, TypeAlias

__all__ = ["JsonObject", "JsonValue", "nan_to_null"]

#: A JSON value: text, a number, true/false, null, an array or an object
#: (read-only views, so a list of numbers is one as it stands).
JsonValue: TypeAlias = (
    "str | int | float | bool | Sequence[JsonValue] | Mapping[str, JsonValue] | None")

#: A JSON object being filled in.
JsonObject: TypeAlias = "dict[str, JsonValue]"


def nan_to_null(v: Any) -> Any:
    """``v`` with each float that is not finite (NaN, infinities) as None,
    JSON's null, inside dicts, lists and tuples (as lists) too."""
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, dict):
        return {k: nan_to_null(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [nan_to_null(x) for x in v]
    return v
