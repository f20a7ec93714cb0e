"""Device facades, generated from one declarative register map each.

    from pymb.devices import CoolPro, SensorHub, CoolProStatus, decode_hub
    from pymb.devices import MapDevice      # any device from its pymb.map/1 map

See :mod:`pymb.devices.maps` for the maps (the only place register numbers
appear), :mod:`pymb.maps.planner` for the read planner.
"""

from __future__ import annotations

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
from pymb.devices.maps import COOLPRO, HUB
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
