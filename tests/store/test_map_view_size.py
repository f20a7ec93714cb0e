"""A map's readings view writes each point's bytes as an integer once (an
inner select's column) and names it where the value's SQL uses it: SQLite
keeps every view of the file parsed in memory, and a float's SQL uses its
bytes several times (a 1,000-point f32 map's view took 260 MB of the
logger's RSS written out in full). The values are those the C decoder
makes of the same registers."""

from __future__ import annotations

import math
import random
import sqlite3
import struct
from array import array

from pymb.bench.gatebench import PEERS_POINTS
from pymb.maps import Decoder, loads
from pymb.store.mapviews import create_map_views, view_names
from pymb.store.schema import wire_bytes


def test_a_thousand_f32_points_view_is_short_and_decodes_as_the_c_decoder() -> None:
    m = loads(PEERS_POINTS)
    rng = random.Random(7)
    floats = [rng.uniform(-1e6, 1e6) for _ in range(999)] + [math.nan]
    regs = array("H", struct.unpack(">2000H", struct.pack(">1000f", *floats)))
    db = sqlite3.connect(":memory:")
    db.executescript(
        "CREATE TABLE devices(id INTEGER PRIMARY KEY, bus, port, type, address, name, channels,"
        " humidity_units);"
        "CREATE TABLE samples(id INTEGER PRIMARY KEY, device_id, time_utc, monotonic, registers,"
        " unsupported)")
    db.execute("INSERT INTO devices VALUES (1, 'b', 'p', 'peers-1000', 1, 'd', 0, 'group=')")
    db.execute("INSERT INTO samples VALUES (1, 1, 0.0, 0.0, ?, 0)", (wire_bytes(regs),))
    create_map_views(db, m)
    readings, _ = view_names(m.id)
    (sql,) = db.execute("SELECT sql FROM sqlite_master WHERE name = ?", (readings,)).fetchone()
    assert len(sql) < 1500 * len(m.points)  # about 5,400 a point written out in full
    row = db.execute(f'SELECT * FROM "{readings}"').fetchone()
    names = [d[0] for d in db.execute(f'SELECT * FROM "{readings}"').description]
    got = dict(zip(names, row, strict=True))
    want = Decoder(m, table="input", address=0).read(list(regs))
    assert want["v999"] is None  # a NaN: no value
    assert got["v999"] is None
    for name, value in want.items():
        assert got[name] == value, name
