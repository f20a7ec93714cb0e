"""Device models: a CoolPro (:mod:`pymb.sim.coolpro`) and a sensor hub
(:mod:`pymb.sim.hub`), as pure functions of requests, on the base of
:mod:`pymb.sim.base`.

A device takes a request PDU (function code first) and returns the reply PDU,
or ``None`` for silence; it does no I/O and knows nothing of framing or
timing, which the bus adds (:mod:`pymb.sim.bus`). Every address, block,
range, write limit, firmware profile, reset value, baud table and status bit
comes from :mod:`pymb.devices.maps`; no register number appears here.
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
from pymb.sim.coolpro import CoolProDevice
from pymb.sim.hub import Channel, HubDevice

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
