"""A write never sends NaN or an infinity to a float point (a setpoint of no
value): refused before anything is sent, as an integer point refuses them,
while encoding one (Map.encode, the simulator's NaN fault) still takes them."""

from __future__ import annotations

import math
import struct
from pathlib import Path

import pytest
from conftest import run_pymb

from pymb import InvalidArgument, maps
from pymb.devices.mapwrite import check

GAIN = """
schema = "pymb.map/1"
[device]
id = "amp"
table = "holding"
[[point]]
name = "gain"
address = 30
type = "f32"
access = "rw"
"""


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_a_float_point_refuses_what_is_not_finite(value: float) -> None:
    m = maps.loads(GAIN)
    with pytest.raises(InvalidArgument, match="not a finite number"):
        check(m, [("gain", None, value)])
    regs = m.encode("gain", value)
    got = struct.unpack(">f", struct.pack(">HH", *regs))[0]
    assert math.isnan(got) if math.isnan(value) else got == value


def test_pymb_write_refuses_nan_with_exit_2(tmp_path: Path) -> None:
    (tmp_path / "amp.toml").write_text(GAIN)
    for text in ("nan", "inf", "-inf"):
        r = run_pymb("write", "--map", str(tmp_path / "amp.toml"), "amp:1", f"gain={text}",
                     "--dry-run", "--tcp", "127.0.0.1:1")
        assert r.returncode == 2, (r.stdout, r.stderr)
        assert r.stderr.count("\n") == 1, r.stderr
        assert "not a finite number" in r.stderr, r.stderr
        assert r.stdout == ""
