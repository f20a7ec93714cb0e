"""A reading as plain data: the one JSON-ready form of a hub sweep or a
CoolPro telemetry read, used by ``pymb read``/``watch --json``, the JSON
Lines sink and (through the SQLite log) the MQTT payloads.

Which CoolPro quantities are integers comes from the register map (a
register with no scale is counted, not measured); a value that is not there
(NaN) is ``None``.
"""

from __future__ import annotations

import math
from typing import Any

from pymb import maps
from pymb.devices.coolpro import CoolProStatus, CoolProTelemetry
from pymb.devices.hub import HubReading, State
from pymb.devices.hubreading import BLOCKS
from pymb.devices.mapreading import MapReading

__all__ = [
    "INTEGRAL_QUANTITIES",
    "STATE_NAMES",
    "reading_dict",
    "status_flags",
    "telemetry_values",
]

_TELEMETRY = [(p.name, (p.scale or 1) == 1) for p in maps.builtin("coolpro").points.values()
              if p.group == "telemetry"]
#: The CoolPro quantities that are integers (counts and bit fields), from the map.
INTEGRAL_QUANTITIES = frozenset(name for name, integral in _TELEMETRY if integral)
#: A value state (:class:`pymb.devices.State`) as output names it: "value", "offline", ...
STATE_NAMES = {s.value: s.name.lower() for s in State}


def telemetry_values(t: CoolProTelemetry) -> dict[str, int | float | None]:
    """The telemetry's quantities by name: integers where the map's register
    has no scale, ``None`` for no value."""
    out: dict[str, int | float | None] = {}
    for name, integral in _TELEMETRY:
        v = getattr(t, name)
        out[name] = int(v) if integral else (None if math.isnan(v) else float(v))
    return out


def status_flags(status: int) -> list[str]:
    """The names of the CoolPro status bits set in ``status``."""
    flags = CoolProStatus(status)
    return [f.name for f in CoolProStatus if f in flags and f.name is not None]


def _clean(v: Any) -> Any:
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, list):
        return [_clean(x) for x in v]
    return v


def reading_dict(data: HubReading | CoolProTelemetry | MapReading) -> dict[str, Any]:
    """``values`` and, for a hub, ``states`` (one name per channel) and
    ``unsupported``; for a CoolPro, ``status_flags``; for a map device,
    ``values`` and ``states`` by point name (blocks as lists), the
    ``group`` read and the points ``unsupported``."""
    if isinstance(data, MapReading):
        return {"values": {k: _clean(v) for k, v in data.values.items()},
                "states": dict(data.states), "group": data.group,
                "unsupported": list(data.unsupported)}
    if isinstance(data, HubReading):
        return {"values": data.as_dict(),
                "states": {b.name: [STATE_NAMES[s] for s in data.states(b.name).tolist()]
                           for b in BLOCKS},
                "unsupported": sorted(data.unsupported)}
    return {"values": telemetry_values(data), "status_flags": status_flags(int(data.status))}
