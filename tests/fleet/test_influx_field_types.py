"""InfluxDB line protocol keeps one type per field whatever the value: a
``u64`` point is an unsigned integer (``u``) below and above 2**63, so
InfluxDB never sees a field-type conflict between two samples."""

from __future__ import annotations

import re
from array import array
from pathlib import Path

from pymb import maps
from pymb.devices.mapreading import MapReading, group_layout, group_points
from pymb.store import DeviceInfo, Sample
from pymb.store.influx import InfluxSink

MAP = '''schema = "pymb.map/1"
[device]
id = "big-counter"
table = "holding"
[groups]
g = { interval = 1 }
[[point]]
name = "u64big"
address = 0
type = "u64"
group = "g"
[[point]]
name = "i64"
address = 4
type = "i64"
group = "g"
[[point]]
name = "u32"
address = 8
type = "u32"
group = "g"
'''


def _reading(m: maps.Map, u64: int, i64: int, u32: int) -> MapReading:
    dec = group_layout(m, "g")[0]
    words = array("H", [*(u64 >> s & 0xFFFF for s in (48, 32, 16, 0)),
                        *((i64 & (1 << 64) - 1) >> s & 0xFFFF for s in (48, 32, 16, 0)),
                        u32 >> 16, u32 & 0xFFFF])
    b = dec.decode(words)
    names = group_points(m, "g")
    values, states = dec.values(b), dec.states(b)
    return MapReading(m, "g", {n: values[n] for n in names}, {n: states[n] for n in names},
                      words)


def test_a_u64_field_is_unsigned_whatever_its_value(tmp_path: Path) -> None:
    m = maps.loads(MAP)
    info = DeviceInfo("bus1", "127.0.0.1:502", "big-counter", 1, "meter", map_source=MAP)
    out = tmp_path / "lines.txt"
    sink = InfluxSink(str(out))
    for i, (u64, i64, u32) in enumerate([(12345678901234, -5, 7), ((1 << 64) - 2, 1 << 62,
                                                                   (1 << 32) - 1)]):
        sink.write(Sample(info, 1_700_000_000.0 + i, float(i), _reading(m, u64, i64, u32)))
    sink.close()
    fields = [dict(f.split("=", 1) for f in line.split(" ")[1].split(","))
              for line in out.read_text().splitlines()]
    assert [f["u64big"] for f in fields] == ["12345678901234u", "18446744073709551614u"]
    assert [f["i64"] for f in fields] == ["-5i", f"{1 << 62}i"]
    assert [f["u32"] for f in fields] == ["7i", "4294967295i"]
    for f in fields:  # the same suffix for a field in every line
        assert {re.sub(r"^-?[0-9]+", "", v) for v in f.values()} <= {"i", "u"}
