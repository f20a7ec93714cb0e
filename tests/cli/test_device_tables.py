"""``pymb log --config``: a mistake in a hub's or a CoolPro's ``[[bus.device]]``
table is one line naming the file, the bus, the device and the key, with what
the key takes (the known keys for an unknown one, a whole number where one
is needed), the range without repeating the key; nothing is created."""

from __future__ import annotations

from pathlib import Path

import pytest
from clikit import no_traceback
from conftest import run_pymb

KNOWN = "type, map, address, name, groups, offline_after, offline_retry, deadband"


@pytest.mark.parametrize(("device", "line"), [
    ('type = "hub"\ncolour = "red"',
     f"bus 1, device 1 [[bus.device]]: unknown key 'colour'; known: {KNOWN}, channels, "
     "humidity_unit"),
    ('type = "coolpro"\nchannels = 50',
     f"bus 1, device 1 [[bus.device]]: unknown key 'channels'; known: {KNOWN}"),
    ('type = "hub"\nadress = 7',
     "bus 1, device 1 [[bus.device]]: unknown key 'adress'; did you mean 'address'?"),
    ('type = "hub"\naddress = 0', "bus 1, device 1: hub address must be 1..255, got 0"),
    ('type = "coolpro"\naddress = 248', "bus 1, device 1: coolpro address must be 1..247, got 248"),
    ('type = "hub"\nchannels = "x"', "bus 1, device 1: channels must be a whole number, got 'x'"),
    ('type = "hub"\nchannels = true', "bus 1, device 1: channels must be a whole number, got True"),
    ('type = "hub"\nhumidity_unit = "1"', "bus 1, device 1: humidity_unit must be a number, "
                                           "got '1'"),
    ('type = "hub"\nhumidity_unit = [1, "x"]', "bus 1, device 1: humidity_unit must be a "
                                                "number, got 'x'"),
    ('type = "hub"\nname = 3', "bus 1, device 1: name must be a string, got 3"),
])
def test_a_device_tables_mistake_names_its_key(tmp_path: Path, device: str, line: str) -> None:
    cfg = tmp_path / "c.toml"
    cfg.write_text(f'[output]\npath = "x.sqlite"\n[[bus]]\nport = "/dev/ttyUSB-none"\n'
                   f"[[bus.device]]\n{device}\n")
    r = run_pymb("log", "--config", "c.toml", "--seconds", "1", cwd=tmp_path)
    no_traceback(r)
    assert r.returncode == 2, r.stderr
    assert r.stderr.strip() == f"pymb log: c.toml: {line}"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.toml"]
