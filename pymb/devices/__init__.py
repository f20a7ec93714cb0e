"""Device facades and their register maps (see :mod:`pymb.devices.maps`)."""

from __future__ import annotations

from pymb.devices.maps import COOLPRO, HUB, HUB_FIRMWARE_PROFILES

__all__ = ["COOLPRO", "HUB", "HUB_FIRMWARE_PROFILES"]
