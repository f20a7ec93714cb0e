"""A reading as plain data: the one JSON-ready form of a reading (a map
device's, a hub sweep or a CoolPro telemetry read), used by ``pymb
read``/``watch --json``, the JSON Lines sink and (through the SQLite log)
the MQTT payloads; and :func:`map_reading`, any reading as the
:class:`~pymb.devices.mapreading.MapReading` of its map (the one form the
logger and the store work with).

Which CoolPro quantities are integers comes from the register map (a
register with no scale is counted, not measured); a value that is not there
(NaN) is ``None``.
"""

from __future__ import annotations

import functools
import math
from array import array
from typing import Any

from pymb import maps
from pymb.devices.coolpro import (
    CoolProIdentity,
    CoolProStatus,
    CoolProTelemetry,
    decode_identity,
    decode_telemetry,
)
from pymb.devices.hub import HubReading, State
from pymb.devices.hubreading import BLOCKS, HUB_REGISTERS
from pymb.devices.mapreading import Blocks, MapReading
from pymb.jsonvalue import nan_to_null
from pymb.maps import Map
from pymb.maps.types import STATES

__all__ = [
    "INTEGRAL_QUANTITIES",
    "STATE_NAMES",
    "Reading",
    "has_own_view",
    "identity_view",
    "map_reading",
    "reading_dict",
    "reading_view",
    "status_flags",
    "telemetry_values",
]

_HUB, _COOLPRO = maps.builtin("hub"), maps.builtin("coolpro")
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


def map_reading(data: HubReading | CoolProTelemetry | MapReading) -> MapReading:
    """``data`` as a :class:`MapReading` of its map: a hub's sweep (every
    block channel by channel, the registers 31..730 it read) or a CoolPro's
    telemetry; a map reading as it is."""
    if isinstance(data, MapReading):
        return data
    if isinstance(data, HubReading):
        b = Blocks([p.name for p in BLOCKS], data.channels, array("d", data.values),
                   array("B", data.raw_states))
        gone = tuple(p.name for p in BLOCKS if p.name in data.unsupported)
        return MapReading(_hub_map(data.channels), "sweep", b.value_map(), b.state_map(),
                          array("H", data.registers), gone)
    got: dict[str, Any] = telemetry_values(data)
    return MapReading(_COOLPRO, "telemetry", got,
                      {n: "value" if v is not None else "nan" for n, v in got.items()},
                      array("H", data.registers))


@functools.lru_cache(maxsize=128)
def _hub_map(channels: int) -> Map:
    return _HUB.configure(channels=channels) if channels != _HUB.options["channels"] else _HUB


def _hub_dict(data: MapReading) -> dict[str, Any]:
    return {"values": nan_to_null(dict(data.values)),
            "states": dict(data.states), "unsupported": sorted(data.unsupported)}


def _coolpro_dict(data: MapReading) -> dict[str, Any]:
    values: dict[str, Any] = {}
    for name, integral in _TELEMETRY:
        v = data.values.get(name)
        values[name] = (int(v) if integral else float(v)) if isinstance(
            v, (int, float)) and v == v else None
    status = values.get("status")
    return {"values": values, "status_flags": status_flags(status) if status is not None
            else []}


def reading_dict(data: HubReading | CoolProTelemetry | MapReading) -> dict[str, Any]:
    """``values`` and, for a hub, ``states`` (one name per channel) and
    ``unsupported``; for a CoolPro, ``status_flags``; for a map device,
    ``values`` and ``states`` by point name (blocks as lists), the
    ``group`` read and the points ``unsupported``."""
    data = map_reading(data)
    view = _VIEWS.get(data.map.device.view)
    if view is not None:
        return view(data)
    return {"values": nan_to_null(dict(data.values)),
            "states": dict(data.states), "group": data.group,
            "unsupported": list(data.unsupported)}


#: the JSON of a reading by the typed view its map names (``[device] view``:
#: the hub's sweep, the CoolPro's telemetry), as ``SensorHub``/``CoolPro``
#: readings always gave it
_VIEWS = {"hub": _hub_dict, "coolpro": _coolpro_dict}

#: A reading as a device gives it: a map reading, or the typed view of the
#: hub's sweep or of the CoolPro's telemetry.
Reading = HubReading | CoolProTelemetry | MapReading


def _hub_view(data: MapReading) -> HubReading:
    c = max(p.channels for p in data.map.points.values() if p.block)
    regs = array("H", data.registers[:HUB_REGISTERS])
    if len(regs) < HUB_REGISTERS:
        regs.frombytes(bytes(2 * (HUB_REGISTERS - len(regs))))
    r = HubReading(c, regs)
    b = data.blocks
    for k, p in enumerate(BLOCKS):
        if b is not None and p.name in b.index:
            at = b.index[p.name]
            r.values[k * c:(k + 1) * c] = b.values[at:at + c]
            r.raw_states[k * c:(k + 1) * c] = b.states[at:at + c]
        elif p.name in data.values:
            vs, sts = data.values[p.name], data.states[p.name]
            assert isinstance(vs, list)
            r.values[k * c:(k + 1) * c] = array(
                "d", [float(v) if isinstance(v, int | float) else math.nan for v in vs])
            r.raw_states[k * c:(k + 1) * c] = array("B", [STATES.index(s) for s in sts])
    r.unsupported_mask = sum(1 << k for k, p in enumerate(BLOCKS) if p.name in data.unsupported)
    return r


def has_own_view(data: Reading) -> bool:
    """Whether a reading's outputs take its device's own form (the hub's
    sweep channel by channel, the CoolPro's telemetry: their JSON, line
    protocol and Sparkplug metrics, as ``SensorHub``/``CoolPro`` readings
    always gave them) rather than a map device's."""
    return map_reading(data).map.device.view in _VIEWS


def reading_view(data: MapReading) -> Reading:
    """The public view of a map reading: a reading of the hub's map as the
    :class:`~pymb.devices.HubReading` ``SensorHub`` gives (registers
    31..730, its channels' values and states, the blocks the firmware
    lacks), of the CoolPro's telemetry as the
    :class:`~pymb.devices.CoolProTelemetry` ``CoolPro`` gives; any other as
    it is."""
    view = data.map.device.view
    if view == "hub":
        return _hub_view(data)
    if view == "coolpro" and data.group == "telemetry":
        return decode_telemetry(array("H", data.registers))
    return data


def identity_view(data: MapReading) -> CoolProIdentity | MapReading:
    """A reading of a map's ``identity`` group as its view shows it: the
    CoolPro's as the :class:`~pymb.devices.CoolProIdentity` ``CoolPro``
    gives (its serial number, hardware revision, firmware version and
    manufacture date); any other as it is."""
    if data.map.device.view == "coolpro" and data.group == "identity":
        return decode_identity(array("H", data.registers))
    return data
