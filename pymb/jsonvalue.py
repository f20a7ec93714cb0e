"""JSON as pymb holds it: :data:`JsonValue`, what :func:`json.loads` gives and
:func:`json.dumps` takes, and :data:`JsonObject`, an object being built."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TypeAlias

__all__ = ["JsonObject", "JsonValue"]

#: A JSON value: text, a number, true/false, null, an array or an object
#: (read-only views, so a list of numbers is one as it stands).
JsonValue: TypeAlias = (
    "str | int | float | bool | Sequence[JsonValue] | Mapping[str, JsonValue] | None")

#: A JSON object being filled in.
JsonObject: TypeAlias = "dict[str, JsonValue]"
