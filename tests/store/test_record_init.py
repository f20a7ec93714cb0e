"""The two records a logger makes per poll, :class:`pymb.store.Sample` and
:class:`pymb.devices.mapreading.MapReading`, write their own constructors
(their fields straight into the instance's ``__dict__``, for speed): each
still sets exactly its declared fields, by position and by name, with the
declared defaults, stays frozen and compares, hashes, prints and copies
(``dataclasses.replace``) as the dataclass it is."""

from __future__ import annotations

import dataclasses
import inspect
from array import array
from typing import Any

import pytest

from pymb import maps
from pymb.devices.mapreading import MapReading
from pymb.store import DeviceInfo, Sample

MAP = """schema = "pymb.map/1"
[device]
id = "records"
table = "holding"

[[point]]
name = "t"
address = 0
type = "u16"
"""


def _fields(cls: type) -> list[dataclasses.Field[Any]]:
    return list(dataclasses.fields(cls))


@pytest.mark.parametrize("cls", [Sample, MapReading])
def test_the_constructor_takes_exactly_the_fields_with_their_defaults(cls: type) -> None:
    params = list(inspect.signature(cls).parameters.values())
    fields = _fields(cls)
    assert [p.name for p in params] == [f.name for f in fields]
    for p, f in zip(params, fields, strict=True):
        want = inspect.Parameter.empty if f.default is dataclasses.MISSING else f.default
        assert p.default == want, f.name


def _reading(**over: Any) -> MapReading:
    m = maps.loads(MAP)
    args: dict[str, Any] = {"map": m, "group": None, "values": {"t": 7}, "states": {"t": "ok"},
                            "registers": array("H", [7])}
    args.update(over)
    return MapReading(**args)


def test_a_map_reading_sets_every_field_and_stays_frozen() -> None:
    r = _reading(wire=b"\x00\x07")
    assert sorted(vars(r)) == sorted(f.name for f in _fields(MapReading))
    assert (r.group, r.values, r.unsupported, r.wire) == (None, {"t": 7}, (), b"\x00\x07")
    with pytest.raises(dataclasses.FrozenInstanceError):
        r.group = "x"  # type: ignore[misc]
    # positional and keyword construction agree; wire does not take part in ==
    same = MapReading(r.map, None, {"t": 7}, {"t": "ok"}, array("H", [7]))
    assert same == r
    assert same.wire is None
    assert repr(same) == repr(_reading())
    assert dataclasses.replace(r, unsupported=("t",)).unsupported == ("t",)


def test_a_sample_sets_every_field_and_stays_frozen() -> None:
    info = DeviceInfo(bus="b", port="127.0.0.1:502", type="records", address=3, name="m")
    reading = _reading()
    s = Sample(info, 1.5, 2.5, reading)
    assert vars(s) == {"device": info, "time_utc": 1.5, "monotonic": 2.5, "data": reading}
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.time_utc = 0.0  # type: ignore[misc]
    assert Sample(device=info, time_utc=1.5, monotonic=2.5, data=reading) == s
    assert dataclasses.replace(s, monotonic=9.0).monotonic == 9.0
    assert "time_utc=1.5" in repr(s)
