"""Device facades, generated from one declarative register map each.

    from pymb.devices import CoolPro, SensorHub, CoolProStatus, decode_hub
    from pymb.devices import MapDevice      # any device from its pymb.map/1 map

``HUB`` and ``COOLPRO`` are the two devices' shipped maps
(``pymb.maps.builtin("hub")``, ``("coolpro")``: the only place their register
numbers appear); :mod:`pymb.maps.planner` is the read planner.
"""

from __future__ import annotations

from pymb import maps
from pymb.devices.coolpro import (
    CoolPro,
    CoolProConfig,
    CoolProIdentity,
    CoolProStatus,
    CoolProTelemetry,
)
from pymb.devices.hub import HubChannel, HubReading, SensorHub, State, decode_hub
from pymb.devices.hubreading import HUB_FIRMWARE_PROFILES
from pymb.devices.mapdevice import MapDevice
from pymb.maps.planner import ReadPlan

__all__ = [
    "COOLPRO",
    "HUB",
    "HUB_FIRMWARE_PROFILES",
    "CoolPro",
    "CoolProConfig",
    "CoolProIdentity",
    "CoolProStatus",
    "CoolProTelemetry",
    "HubChannel",
    "HubReading",
    "MapDevice",
    "ReadPlan",
    "SensorHub",
    "State",
    "decode_hub",
]

#: The sensor hub's shipped map, ``pymb.maps.builtin("hub")``.
HUB = maps.builtin("hub")
#: The CoolPro's shipped map, ``pymb.maps.builtin("coolpro")``.
COOLPRO = maps.builtin("coolpro")
