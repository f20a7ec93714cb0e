"""A hub's channels in the store: a :class:`~pymb.store.DeviceInfo` that
leaves them at 0 takes them as read (its docstring's promise), so a sweep of
a 50-channel hub is stored and read back with 50 channels, not 100."""

from __future__ import annotations

import io
import sqlite3
import time
from array import array
from pathlib import Path

import pytest

from pymb.devices import HubReading, decode_hub
from pymb.store import DeviceInfo, Sample, SqliteSink, export_csv, samples_after


@pytest.mark.parametrize("given", [0, 50])
def test_a_hub_sweep_of_50_channels_is_stored_with_50(tmp_path: Path, given: int) -> None:
    db = tmp_path / "d.sqlite"
    regs = array("H", [(k * 7) & 0x7FFF for k in range(700)])
    reading = decode_hub(regs, channels=50)
    sink = SqliteSink(db)
    sink.write(Sample(DeviceInfo("b", "/dev/null", "hub", 1, "hub-1", channels=given),
                      time.time(), 0.0, reading))
    sink.commit()
    sink.close()
    con = sqlite3.connect(db)
    try:
        assert con.execute("SELECT MAX(channel) FROM channels").fetchone()[0] == 50
    finally:
        con.close()
    (back,) = samples_after(db, 0)
    assert isinstance(back.data, HubReading)
    assert back.data.channels == 50
    assert back.data.values == reading.values
    out = io.StringIO()
    export_csv(str(db), out)
    rows = out.getvalue().splitlines()[1:]
    assert {int(r.split(",")[6]) for r in rows} == set(range(1, 51))
