"""SunSpec devices: every SunSpec model as a ``pymb.map/1`` map, and
discovery of a device's models.

    from pymb.maps import sunspec

    sunspec.model_ids()                          # (1, 2, 3, ..., 64414)
    m = sunspec.model_map(103)                   # model 103 alone, at 40002
    m.points["inverter.W"].scale_from            # "inverter.W_SF"
    found = sunspec.discover(lambda a, n: client.read_holding_registers(a, n, slave=1))
    found.map(unit=1)                            # the device's map

The models are the SunSpec Alliance's own definitions (Apache-2.0, see
``NOTICE``); :mod:`pymb.maps.sunspec.layout` converts them, and
:mod:`pymb.maps.sunspec.discover` walks a device's model chain. See
``docs/sunspec.md``.
"""

from __future__ import annotations

from pymb import maps
from pymb.maps.model import Map
from pymb.maps.sunspec.discover import BASES, Discovery, NotSunSpec, Reader, discover
from pymb.maps.sunspec.layout import (
    NOT_IMPLEMENTED,
    Placed,
    map_text,
    model_def,
    model_ids,
    model_length,
)

__all__ = ["BASES", "NOT_IMPLEMENTED", "Discovery", "NotSunSpec", "Placed", "Reader",
           "discover", "map_text", "model_def", "model_ids", "model_length", "model_map",
           "model_text"]


def model_text(model_id: int, *, repeats: int = 1, unit: int = 1) -> str:
    """The map (TOML) of a device holding model ``model_id`` alone: ``SunS``
    at 40000, the model at 40002, ``repeats`` instances of each repeating
    group, the end marker after it."""
    length = model_length(model_id, repeats)
    name = str(model_def(model_id)["group"]["name"])
    return map_text([Placed(model_id, 40002, length, name)], base=40000, unit=unit,
                    device_id=f"sunspec-{model_id}", end=40002 + 2 + length + 2)


def model_map(model_id: int, *, repeats: int = 1) -> Map:
    """:func:`model_text`, loaded."""
    return maps.loads(model_text(model_id, repeats=repeats), source=f"sunspec model {model_id}")
