"""Device models: every simulated device is a map's
(:class:`~pymb.sim.mapsim.MapSimDevice`); the CoolPro
(:mod:`pymb.sim.coolprosim`) and the sensor hub (:mod:`pymb.sim.hubsim`)
add their own behaviours to their shipped maps, on the base of
:mod:`pymb.sim.base`.

A device takes a request PDU (function code first) and returns the reply PDU,
or ``None`` for silence; it does no I/O and knows nothing of framing or
timing, which the bus adds (:mod:`pymb.sim.bus`). Every address, block,
range, write limit, firmware, reset value, baud table and status bit comes
from the maps (``pymb map show coolpro``); no register number appears here.
"""

from __future__ import annotations

from pymb.sim.base import (
    Device,
    ExceptionCode,
    Function,
    exception_pdu,
    parse_firmware,
    sign_magnitude,
)
from pymb.sim.coolprosim import CoolProDevice
from pymb.sim.hubsim import Channel, HubDevice

__all__ = [
    "Channel",
    "CoolProDevice",
    "Device",
    "ExceptionCode",
    "Function",
    "HubDevice",
    "exception_pdu",
    "parse_firmware",
    "sign_magnitude",
]
