"""Device maps as data: the ``pymb.map/1`` format.

    from pymb import maps

    m = maps.load("eastron-sdm120.toml")     # or maps.loads(text), maps.builtin("coolpro")
    m.points["voltage_v"].type                 # "f32"
    m.decode("voltage_v", [0x4366, 0x8000])    # 230.5
    m.encode("relay_on", True)                 # [1]

A map names each value of a device (where it lives, its type, byte order,
scale, markers, access) and how the device wants to be asked; see
``docs/maps.md``. Every mistake in a file is one :class:`MapError` naming the
file, the point and the key.
"""

from __future__ import annotations

import functools
from importlib import resources

from pymb.maps._decode import Buffers, Decoder
from pymb.maps.loader import load, loads
from pymb.maps.model import (
    DeviceSection,
    Identify,
    Limits,
    Map,
    MapError,
    Point,
    PointState,
    Timing,
    Value,
    did_you_mean,
)
from pymb.maps.types import STATES, TYPES

__all__ = [
    "STATES",
    "TYPES",
    "Buffers",
    "Decoder",
    "DeviceSection",
    "Identify",
    "Limits",
    "Map",
    "MapError",
    "Point",
    "PointState",
    "Timing",
    "Value",
    "builtin",
    "builtin_ids",
    "load",
    "loads",
]


def builtin_ids() -> list[str]:
    """The ids of the maps shipped with pymb, sorted."""
    folder = resources.files("pymb.maps") / "builtin"
    return sorted(f.name[:-5] for f in folder.iterdir() if f.name.endswith(".toml"))


def builtin(id: str) -> Map:
    """The shipped map of device ``id`` (``"coolpro"``, ``"hub"``, ...)."""
    if not isinstance(id, str):
        raise MapError(f"a built-in map's id is text, got {id!r}", key=str(id))
    return _builtin(id)


@functools.cache  # a few dozen small, immutable maps
def _builtin(id: str) -> Map:
    known = builtin_ids()
    if id not in known:
        raise MapError(f"no built-in map {id!r}{did_you_mean(id, known)}", key=id)
    res = resources.files("pymb.maps") / "builtin" / f"{id}.toml"
    return loads(res.read_text(encoding="utf-8"), source=f"builtin:{id}")
