"""Every point of a map must fit one request: a point (a block's channel)
wider than ``[device.limits] max_registers`` could never be read, so it is a
MapError when the map loads (``pymb map check`` says so), naming the file,
the point and the key, not a failure in the middle of a run."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import run_pymb

from pymb import maps

HEAD = """schema = "pymb.map/1"
[device]
id = "narrow"
table = "holding"
[device.limits]
max_registers = {most}
single_point_requests = {single}
"""
BODY = """[[point]]
name = "volts"
address = 0
type = "u16"
[[point]]
name = "energy_wh"
address = 2
type = "u64"
"""


@pytest.mark.parametrize("single", ["false", "true"])
def test_a_point_wider_than_max_registers_is_a_map_error(single: str) -> None:
    with pytest.raises(maps.MapError) as info:
        maps.loads(HEAD.format(most=2, single=single) + BODY, source="n.toml")
    e = info.value
    assert (e.source, e.point, e.key) == ("n.toml", "energy_wh", "max_registers")
    assert str(e) == ("n.toml: point 'energy_wh': key 'max_registers': the point is 4 "
                      "registers (u64) but [device.limits] max_registers = 2 allows at most "
                      "2 per request; raise max_registers to at least 4")
    # wide enough: loads
    assert maps.loads(HEAD.format(most=4, single=single) + BODY).points["energy_wh"].count == 4


def test_a_block_channel_and_a_string_count_too() -> None:
    block = '[[block]]\nname = "t"\nfirst = 0\ncount = 3\nstride = 4\ntype = "f32"\n'
    with pytest.raises(maps.MapError, match=r"point 't': key 'max_registers': the point is 2"):
        maps.loads(HEAD.format(most=1, single="false") + block)
    assert maps.loads(HEAD.format(most=2, single="false") + block).points["t"].channels == 3
    text = '[[point]]\nname = "serial"\naddress = 0\ntype = "string"\ncount = 8\n'
    with pytest.raises(maps.MapError, match=r"point 'serial': key 'max_registers': .* 8"):
        maps.loads(HEAD.format(most=5, single="false") + text)


def test_map_check_and_log_refuse_it_in_one_line(tmp_path: Path) -> None:
    f = tmp_path / "narrow.toml"
    f.write_text(HEAD.format(most=2, single="false") + BODY)
    for args in (("map", "check", str(f)),
                 ("log", "--map", str(f), "--tcp", "127.0.0.1:1", "narrow:7", "--seconds", "1",
                  "--out", str(tmp_path / "n.sqlite"))):
        r = run_pymb(*args)
        assert r.returncode == 2, r.stderr
        assert r.stderr.count("\n") == 1, r.stderr
        assert "point 'energy_wh': key 'max_registers'" in r.stderr
    assert not (tmp_path / "n.sqlite").exists()
