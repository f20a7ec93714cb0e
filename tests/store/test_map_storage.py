"""A map device's stored samples: the views generated from its map decode
the stored registers exactly as the C decoder does (every shipped map, every
group, random registers), and the storage documentation's "value at time t"
query works for any map."""

from __future__ import annotations

import math
import random
import sqlite3
import time
from array import array
from pathlib import Path
from typing import Any

import pytest

from pymb import maps
from pymb.devices.mapreading import MapReading, group_layout, group_points
from pymb.devices.mapspec import TYPED_VIEWS
from pymb.maps import Map, Point
from pymb.store import DeviceInfo, Sample, SqliteSink, samples_after
from pymb.store.mapviews import view_names
from pymb.store.text import sample_rows

SHIPPED = [i for i in maps.builtin_ids() if i not in TYPED_VIEWS]

#: every type and byte order, bit fields, halves, markers, a string, scale
#: and offset, a block
EVERY_TYPE = '''schema = "pymb.map/1"
[device]
id = "every-type"
table = "holding"
[groups]
a = { interval = 1 }
b = { interval = 0 }
[[point]]
name = "u16"
address = 0
type = "u16"
group = "a"
markers = { 0xFFFF = "offline" }
[[point]]
name = "i16"
address = 1
type = "i16"
scale = 0.1
group = "a"
deadband = 5.0
[[point]]
name = "u32_cdab"
address = 2
type = "u32"
order = "CDAB"
group = "a"
[[point]]
name = "i32_badc"
address = 4
type = "i32"
order = "BADC"
offset = -40
group = "a"
[[point]]
name = "u64"
address = 6
type = "u64"
group = "a"
[[point]]
name = "i64_dcba"
address = 10
type = "i64"
order = "DCBA"
group = "a"
[[point]]
name = "f64"
address = 14
type = "f64"
group = "a"
deadband = 0
[[point]]
name = "f32_dcba"
address = 18
type = "f32"
order = "DCBA"
scale = 2.5
group = "a"
[[point]]
name = "sm16"
address = 20
type = "sm16"
scale = 0.01
group = "a"
[[point]]
name = "bit3"
address = 21
type = "bit"
bit = 3
group = "b"
[[point]]
name = "field"
address = 21
type = "bits"
shift = 4
width = 5
group = "b"
[[point]]
name = "hi"
address = 22
type = "i8_hi"
group = "b"
[[point]]
name = "lo"
address = 22
type = "u8_lo"
group = "b"
[[point]]
name = "text"
address = 23
type = "string"
count = 4
group = "b"
[[point]]
name = "f16"
address = 27
type = "f16"
group = "b"
[[point]]
name = "text_badc"
address = 40
type = "string"
count = 3
order = "BADC"
group = "b"
[[point]]
name = "text_high"
address = 43
type = "string"
count = 3
string_bytes = "high"
group = "b"
[[point]]
name = "text_low_dcba"
address = 46
type = "string"
count = 3
string_bytes = "low"
order = "DCBA"
group = "b"
[[point]]
name = "text_utf8"
address = 49
type = "string"
count = 4
encoding = "utf-8"
group = "b"
[[point]]
name = "text_latin1"
address = 53
type = "string"
count = 3
encoding = "latin-1"
order = "BADC"
group = "b"
[[point]]
name = "text_latin1_low"
address = 56
type = "string"
count = 2
encoding = "latin-1"
string_bytes = "low"
group = "b"
[[point]]
name = "text_high_badc"
address = 58
type = "string"
count = 2
string_bytes = "high"
order = "BADC"
group = "b"
[[point]]
name = "W"
address = 60
type = "i16"
scale_from = "W_SF"
group = "a"
[[point]]
name = "inverter.Hz"
address = 61
type = "u32"
scale_from = "inverter.Hz_SF"
offset = 0.5
group = "a"
[[point]]
name = "W_SF"
address = 63
type = "sunssf"
[[point]]
name = "inverter.Hz_SF"
address = 64
type = "i16"
order = "BA"
group = "b"
[[point]]
name = "eta"
address = 65
type = "u16"
mask = 0x006F
markers = { 0x0020 = "off" }
group = "a"
[[point]]
name = "energy"
address = 66
type = "u32"
markers = { "0x7FFFxxxx" = "overflow" }
group = "a"
[[point]]
name = "big"
address = 68
type = "u64"
order = "CDAB"
mask = 0xFFFF00000000FFFF
markers = { "0xFFFFxxxxxxxxxxxx" = "top" }
group = "a"
[[block]]
name = "temps"
first = 30
count = 4
stride = 2
type = "i16"
scale = 0.5
group = "a"
'''


def _source(map_id: str) -> str:
    from importlib import resources
    if map_id == "every-type":
        return EVERY_TYPE
    return (resources.files("pymb.maps") / "builtin" / f"{map_id}.toml").read_text()


def random_text(rng: random.Random, count: int) -> array[int]:
    """``count`` registers of text in any layout: printable ASCII, a NUL
    somewhere (and text after it), bytes past ASCII, valid UTF-8."""
    kind = rng.randrange(5)
    if kind == 0:
        data = bytes(rng.randrange(0x20, 0x7F) for _ in range(2 * count))
    elif kind == 1:
        data = bytes(rng.choice((0, rng.randrange(1, 0x7F))) for _ in range(2 * count))
    elif kind == 2:
        data = bytes(rng.getrandbits(8) for _ in range(2 * count))
    elif kind == 3:
        data = "".join(rng.choice("aé€x") for _ in range(count)).encode()[:2 * count]
    else:  # a byte or two past ASCII among ASCII letters, with either half empty
        data = bytes(rng.choice((0x41, 0x62, 0xE9, 0x00, 0x7F, 0x80, 0xFF))
                     for _ in range(2 * count))
    data = data.ljust(2 * count, b"\0")
    return array("H", (data[i] << 8 | data[i + 1] for i in range(0, 2 * count, 2)))


def view_value(p: Point, want: Any) -> Any:
    """What the view gives for the decoder's ``want`` of ``p``: a utf-8
    text that is not pure ASCII is NULL (SQL cannot check UTF-8)."""
    if p.type == "string" and p.encoding == "utf-8" and want is not None \
            and not want.isascii():
        return None
    return want


def random_reading(m: Map, group: str | None, rng: random.Random) -> MapReading:
    regs = array("H")
    values: dict[str, Any] = {}
    states: dict[str, Any] = {}
    for dec in group_layout(m, group):
        words = array("H", (rng.getrandbits(16) for _ in range(dec.count)))
        for n in dec.names:
            p = m.points[n]
            if p.type == "string":
                start = p.address - dec.address
                words[start:start + p.span] = random_text(rng, p.span)
            if p.type in ("f32", "f64", "f16") and rng.random() < 0.2:
                for k in range(p.address - dec.address, p.address - dec.address + p.span):
                    words[k] = 0  # zeros and small exponents too
        for n in dec.names:  # scale factors: in SunSpec's range mostly, some not
            p = m.points[n]
            if p.type in ("sunssf", "i16") and n.endswith("_SF"):
                sf = rng.choice((*range(-10, 11), -32768, 11, -11, 32767))
                w = sf & 0xFFFF
                words[p.address - dec.address] = (w >> 8 | (w & 0xFF) << 8) \
                    if p.order == "BA" else w
            if n in ("energy", "big") and rng.random() < 0.3:
                words[p.address - dec.address + 1] = 0x7FFF if n == "energy" else 0xFFFF
        if rng.random() < 0.3:  # the markers of every point
            for n in dec.names:
                p = m.points[n]
                if p.markers and p.count == 1:
                    words[p.address - dec.address] = rng.choice(list(p.markers)) & 0xFFFF
        b = dec.decode(words)
        values.update(dec.values(b))
        states.update(dec.states(b))
        regs.extend(words)
    names = group_points(m, group)
    return MapReading(m, group, {n: values[n] for n in names},
                      {n: states[n] for n in names}, regs)


def same(want: Any, got: Any) -> bool:
    if want is None or (isinstance(want, float) and math.isnan(want)):
        return got is None
    if isinstance(want, bool):
        return bool(got == int(want))
    if isinstance(want, int) and want >= 1 << 63:
        # past SQLite's integers: the view gives the nearest REAL (export is exact)
        return bool(got == float(want))
    return bool(want == got)


@pytest.mark.parametrize("map_id", [*SHIPPED, "every-type"])
def test_the_map_views_decode_exactly_as_the_c_decoder(tmp_path: Path, map_id: str) -> None:
    m = maps.loads(_source(map_id))
    rng = random.Random(map_id)
    db = tmp_path / "v.sqlite"
    sink = SqliteSink(db)
    info = DeviceInfo("bus1", "127.0.0.1:502", map_id, 3, "meter", map_source=_source(map_id))
    written = []
    groups: list[str | None] = list(m.groups) if m.groups else [None]
    t = time.time()
    for i in range(40):
        r = random_reading(m, groups[i % len(groups)], rng)
        sink.write(Sample(info, t + i, float(i), r))
        written.append(r)
    sink.close()
    readings, channels = view_names(map_id)
    con = sqlite3.connect(db)
    con.row_factory = sqlite3.Row
    scalar = {row["sample_id"]: row for row in con.execute(f"SELECT * FROM {readings}")}
    blocks = [p for p in m.points.values() if p.block]
    per_channel = {}
    if blocks:
        per_channel = {(row["sample_id"], row["channel"]): row
                       for row in con.execute(f"SELECT * FROM {channels}")}
    con.close()
    assert len(scalar) == len(written)
    checked = 0
    for sid, r in enumerate(written, 1):
        row = scalar[sid]
        assert row["grp"] == (r.group or "")
        for p in m.points.values():
            if p.access == "w":
                continue
            want = r.values.get(p.name)
            if p.block:
                for c in range(1, p.channels + 1):
                    got = per_channel[(sid, c)][p.name]
                    w = None if want is None else want[c - 1]  # type: ignore[index]
                    assert same(w, got), (p.name, c, w, got)
            else:
                want = view_value(p, want)
                assert same(want, row[p.name]), (p.name, r.group, want, row[p.name])
            checked += p.name in r.values
    assert checked > 0
    # and the reader decodes the same again
    back = samples_after(db, 0, limit=100)
    assert [s.data.values for s in back] == [r.values for r in written]  # type: ignore[union-attr]


def test_the_value_at_time_t_query_for_any_map(tmp_path: Path) -> None:
    """The storage page's query for a map device: the last value of a point
    at or before a time t, on the time index."""
    m = maps.builtin("eastron-sdm120")
    db = tmp_path / "t.sqlite"
    sink = SqliteSink(db)
    info = DeviceInfo("bus1", "127.0.0.1:502", m.id, 3, "meter",
                      map_source=_source(m.id))
    rng = random.Random(1)
    base = 1_700_000_000.0
    volts = {}
    for i in range(200):
        group = "fast" if i % 4 else "energy"
        r = random_reading(m, group, rng)
        sink.write(Sample(info, base + i, float(i), r))
        if group == "fast":
            volts[base + i] = r.values["voltage_v"]
    sink.close()
    con = sqlite3.connect(db)
    query = ("SELECT time, voltage_v FROM eastron_sdm120_readings WHERE device = 'meter' "
             "AND grp = 'fast' AND time_utc <= ? ORDER BY time_utc DESC LIMIT 1")
    t = base + 100.5  # between two samples; sample 100 is an energy sample
    got = con.execute(query, (t,)).fetchone()
    want_t = max(x for x in volts if x <= t)
    assert got[0].startswith(time.strftime("%Y-%m-%dT%H:%M:", time.gmtime(want_t)))
    assert same(volts[want_t], got[1])
    plan = " ".join(str(r) for r in con.execute("EXPLAIN QUERY PLAN " + query, (t,)))
    con.close()
    assert "samples_time" in plan, plan


def test_on_change_by_the_points_deadbands_and_the_heartbeat(tmp_path: Path) -> None:
    """A map reading is stored when a point moved past its deadband (the
    map's, or the device's override), when a state changes, and at the
    heartbeat; not otherwise."""
    from pymb.store import OnChange

    m = maps.loads(EVERY_TYPE)
    db = tmp_path / "oc.sqlite"
    sink = SqliteSink(db, on_change=OnChange(heartbeat=10.0))
    # i16 (scale 0.1) moves by 0.5 at most unless overridden; f64 by the map's 0
    info = DeviceInfo("bus1", "x:502", m.id, 3, "meter", map_source=EVERY_TYPE,
                      map_deadband=(("i16", 0.5),))
    rng = random.Random(5)
    base = random_reading(m, "a", rng)

    def with_values(**changes: Any) -> MapReading:
        values = {**base.values, **changes}
        return MapReading(m, "a", values, base.states, base.registers)

    i16 = base.values["i16"]
    assert isinstance(i16, float)
    steps = [(0.0, with_values(), True),            # the first: stored
             (1.0, with_values(), False),           # nothing moved
             (2.0, with_values(i16=i16 + 0.4), False),  # within the device's 0.5
             (3.0, with_values(i16=i16 + 0.6), True),   # past it
             (4.0, with_values(i16=i16 + 0.6, f64=1.0 if base.values["f64"] != 1.0 else 2.0),
              True),                                # f64: any change
             (5.0, MapReading(m, "a", base.values, {**base.states, "u16": "offline"},
                              base.registers), True),  # a state changed
             (15.1, MapReading(m, "a", base.values, {**base.states, "u16": "offline"},
                               base.registers), True)]  # the heartbeat
    for t, r, _ in steps:
        sink.write(Sample(info, 1_700_000_000 + t, t, r))
    sink.close()
    con = sqlite3.connect(db)
    stored = [t for (t,) in con.execute("SELECT monotonic FROM samples ORDER BY id")]
    con.close()
    assert stored == [t for t, _, keep in steps if keep]


def test_a_files_older_views_are_made_again_when_it_is_logged_to(tmp_path: Path) -> None:
    """Views an older pymb made (a string column as hex, say) are replaced by
    today's the first time a session stores a sample of that map."""
    m = maps.loads(EVERY_TYPE)
    db = tmp_path / "old.sqlite"
    info = DeviceInfo("bus1", "127.0.0.1:502", "every-type", 3, "meter", map_source=EVERY_TYPE)
    rng = random.Random(7)
    first = random_reading(m, "b", rng)
    sink = SqliteSink(db)
    sink.write(Sample(info, time.time(), 0.0, first))
    sink.close()
    readings, _ = view_names("every-type")
    con = sqlite3.connect(db)
    con.execute(f"DROP VIEW {readings}")
    con.execute(f"CREATE VIEW {readings} AS SELECT s.id AS sample_id, hex(s.registers) AS text "
                "FROM samples s")
    con.commit()
    con.close()
    second = random_reading(m, "b", rng)
    sink = SqliteSink(db)
    sink.write(Sample(info, time.time() + 1, 1.0, second))
    sink.close()
    con = sqlite3.connect(db)
    got = [r[0] for r in con.execute(f"SELECT text FROM {readings} ORDER BY sample_id")]
    con.close()
    assert got == [first.values["text"], second.values["text"]]


def test_points_the_device_refused_read_back_unsupported(tmp_path: Path) -> None:
    m = maps.loads(EVERY_TYPE)
    r = random_reading(m, "a", random.Random(3))
    gone = ("i16", "temps")
    values, states = dict(r.values), dict(r.states)
    values["i16"], states["i16"] = None, "unsupported"
    values["temps"], states["temps"] = [None] * 4, ["unsupported"] * 4
    refused = MapReading(m, "a", values, states, r.registers, gone)
    db = tmp_path / "gone.sqlite"
    sink = SqliteSink(db)
    info = DeviceInfo("bus1", "127.0.0.1:502", "every-type", 3, "meter", map_source=EVERY_TYPE)
    sink.write(Sample(info, time.time(), 1.0, refused))
    sink.write(Sample(info, time.time() + 1, 2.0, r))
    sink.close()
    first, second = (s.data for s in samples_after(db, 0))
    assert isinstance(first, MapReading)
    assert isinstance(second, MapReading)
    assert first.unsupported == gone
    assert (dict(first.values), dict(first.states)) == (values, states)
    assert second.unsupported == ()
    assert (dict(second.values), dict(second.states)) == (dict(r.values), dict(r.states))


RAW = '''schema = "pymb.map/1"
[device]
id = "raw-dev"
table = "holding"
[[point]]
name = "blob"
address = 0
type = "raw"
count = 2
[[point]]
name = "t"
address = 2
type = "u16"
'''


def test_a_refused_raw_point_reads_back_as_the_live_read_gave_it(tmp_path: Path) -> None:
    """A ``raw`` point's value is a list of its registers, but refused it is
    one None, ``unsupported``, as MapDevice gives it; the CSV cell is empty."""
    m = maps.loads(RAW)
    values: dict[str, Any] = {"blob": None, "t": 3}
    states: dict[str, Any] = {"blob": "unsupported", "t": "value"}
    db = tmp_path / "raw.sqlite"
    sink = SqliteSink(db)
    info = DeviceInfo("b", "127.0.0.1:502", "raw-dev", 1, "d", map_source=RAW)
    sink.write(Sample(info, time.time(), 1.0,
                      MapReading(m, None, values, states, array("H", [1, 2, 3]), ("blob",))))
    sink.close()
    (s,) = samples_after(db, 0)
    assert isinstance(s.data, MapReading)
    assert (dict(s.data.values), dict(s.data.states)) == (values, states)
    assert [row[-3:] for row in sample_rows(s)] == [["blob", "", "unsupported"],
                                                    ["t", 3, "value"]]
