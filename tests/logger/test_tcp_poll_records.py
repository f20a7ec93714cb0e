"""The records one poll of the TCP loop makes (:func:`pymb.store.block.poll_sample`):
a Sample of a MapReading whose values and states are decoded on first use,
as the device's map decodes the registers, and freed by their reference
counts alone (no cycle: the loop makes one a poll, and a cycle a poll would
run the garbage collector over the whole process every few hundred polls)."""

from __future__ import annotations

import dataclasses
import gc
import struct
import weakref

from pymb import maps
from pymb.devices.mapreading import GroupDecode, MapReading
from pymb.logger.tcpunits import TCP_LINE
from pymb.maps.device_plan import map_planner
from pymb.store import DeviceInfo, Sample
from pymb.store.block import poll_sample

MAP = """schema = "pymb.map/1"
[device]
id = "rec"
table = "holding"

[[point]]
name = "t"
address = 0
type = "i16"
scale = 0.1

[[point]]
name = "n"
address = 1
type = "u32"
"""

INFO = DeviceInfo(bus="b", port="127.0.0.1:502", type="rec", address=1, name="d")


def _how() -> GroupDecode:
    m = maps.loads(MAP)
    _planner, items = map_planner(m, TCP_LINE)
    return GroupDecode(m, None, items)


def test_a_poll_sample_decodes_its_registers_on_first_use() -> None:
    image = struct.pack(">hI", -123, 70000)
    s, r = poll_sample(INFO, 10.5, 3.25, _how(), image)
    assert isinstance(s, Sample)
    assert isinstance(r, MapReading)
    assert (s.device, s.time_utc, s.monotonic, s.data) == (INFO, 10.5, 3.25, r)
    assert list(r.registers) == [0xFF85, 1, 4464]
    assert r.wire == image
    assert dict(r.values) == {"t": -12.3, "n": 70000}
    assert dict(r.states) == {"t": "value", "n": "value"}
    assert r.unsupported == ()


def test_a_poll_sample_is_what_the_records_constructors_make() -> None:
    """poll_sample fills its records in as plain objects and then makes them
    a Sample and a MapReading: they are those classes' own, every field set
    (no other attribute), frozen, equal to and printed as the records the
    constructors make, and the views are whole Mappings."""
    image = struct.pack(">hI", 5, 6)
    s, r = poll_sample(INFO, 10.5, 3.25, _how(), image)
    assert (type(s), type(r)) == (Sample, MapReading)
    assert sorted(vars(s)) == sorted(f.name for f in dataclasses.fields(Sample))
    assert sorted(vars(r)) == sorted(f.name for f in dataclasses.fields(MapReading))
    made = MapReading(r.map, None, r.values, r.states, r.registers, (), image)
    assert r == made
    assert repr(r) == repr(made)
    assert s == Sample(INFO, 10.5, 3.25, made)
    assert hash(s.device) == hash(INFO)
    for record, field in ((s, "time_utc"), (r, "group")):
        try:
            setattr(record, field, 0)
        except dataclasses.FrozenInstanceError:
            continue
        raise AssertionError(f"{type(record).__name__} is not frozen")
    assert dataclasses.replace(s, monotonic=9.0).monotonic == 9.0
    assert list(r.states.values()) == ["value", "value"]
    assert list(r.values.values()) == [0.5, 6]
    assert dict(r.values.items()) == {"t": 0.5, "n": 6}


def test_a_refused_item_reads_unsupported() -> None:
    how = _how()
    _s, r = poll_sample(INFO, 1.0, 1.0, how, bytes(6), frozenset({1}))
    assert r.unsupported == ("n",)
    assert r.values["n"] is None
    assert r.states["n"] == "unsupported"
    assert r.states["t"] == "value"


def test_a_poll_sample_is_freed_without_the_garbage_collector() -> None:
    how = _how()
    gc.collect()
    gc.disable()
    try:
        for _ in range(10):
            s, r = poll_sample(INFO, 1.0, 1.0, how, bytes(6))
            assert r.values["t"] == 0
            assert r.states["n"] == "value"
            gone: list[weakref.ref[object]] = [weakref.ref(s), weakref.ref(r)]
            del s, r
            assert [w() for w in gone] == [None, None]
        assert gc.collect() == 0  # nothing was left in a cycle
    finally:
        gc.enable()
