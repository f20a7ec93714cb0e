"""The same map file given twice (``--map my.toml --map ./my.toml``) is taken
once; two files with one device id are still refused."""

from __future__ import annotations

from pathlib import Path

from conftest import run_pymb

from pymb.sim import SimulatorProcess

MAP = '''schema = "pymb.map/1"
[device]
id = "twice-meter"
table = "holding"
[[point]]
name = "volts"
address = 0
type = "u16"
example = 231
'''


def test_the_same_map_file_twice_is_taken_once(tmp_path: Path) -> None:
    f = tmp_path / "m.toml"
    f.write_text(MAP)
    (tmp_path / "copy.toml").write_text(MAP)
    with SimulatorProcess(["--map", str(f), "twice-meter:7", "--tcp", "127.0.0.1:0"],
                          quiet=True) as sim:
        r = run_pymb("read", "--map", str(f), "--map", "./m.toml", "twice-meter:7",
                     "--tcp", sim.endpoint, cwd=tmp_path)
        assert r.returncode == 0, r.stderr
        assert "231" in r.stdout
        db = tmp_path / "t.sqlite"
        r = run_pymb("log", "--map", str(f), "--map", "./m.toml", "twice-meter:7",
                     "--tcp", sim.endpoint, "--seconds", "0.5", "--interval", "0.1",
                     "--out", str(db), "--quiet", cwd=tmp_path)
        assert r.returncode == 0, r.stderr
        r = run_pymb("read", "--map", str(f), "--map", "copy.toml", "twice-meter:7",
                     "--tcp", sim.endpoint, cwd=tmp_path)
    assert r.returncode == 2
    assert "device id 'twice-meter' is also the id of" in r.stderr
