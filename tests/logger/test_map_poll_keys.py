"""How the logger polls a map's group (``[groups] name = { poll = ... }``) and
a device that fails (``[device.timing] backoff``) is the map's data: a
user's map with the keys the CoolPro's and the hub's maps use is polled as
they are, by ``pymb log`` against a simulator of that map."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import pytest
from clikit import no_traceback
from conftest import run_pymb

from pymb import maps
from pymb.devices.deviceconfig import DeviceConfig, MapText
from pymb.devices.identify import mismatch
from pymb.errors import InvalidArgument
from pymb.sim.simulator import SimulatorProcess

MAP = """schema = "pymb.map/1"
[device]
id = "acme-psu"
table = "input"
[device.timing]
offline_after = 2
backoff = true
[groups]
live = { interval = 30.0, poll = "bus" }
info = { interval = 0, poll = "request" }
[[point]]
name = "volts_v"
address = 0
type = "u16"
scale = 0.1
group = "live"
example = 24.0
[[point]]
name = "serial"
address = 10
type = "u16"
group = "info"
example = 7
"""


def _map(text: str = MAP) -> maps.Map:
    return maps.loads(text, source="acme.toml")


def test_the_keys_load_and_say_how_each_group_is_polled() -> None:
    m = _map()
    assert (m.polled("live"), m.polled("info")) == ("bus", "request")
    assert m.timing.backoff
    assert m.timing.offline_after == 2
    d = DeviceConfig(MapText(m, MAP), 1)
    assert d.groups == ("live",)  # a group on request is not polled by default
    assert d.polls == [("live", None)]  # None: the bus's interval
    with pytest.raises(InvalidArgument, match="group 'info' is read on request, never polled"):
        DeviceConfig(MapText(m, MAP), 1, groups=("live", "info"))
    plain = _map(MAP.replace(', poll = "bus"', "").replace("backoff = true", ""))
    assert plain.polled("live") == "interval"
    assert not plain.timing.backoff
    assert DeviceConfig(MapText(plain, MAP), 1).polls == [("live", 30.0)]


@pytest.mark.parametrize(("old", "new", "says"), [
    ('poll = "bus"', 'poll = "buss"', "poll must be 'interval', 'bus', 'request', got 'buss'"),
    ('poll = "bus"', "poll = 1", "poll must be"),
    ("backoff = true", 'backoff = "yes"', "backoff must be true or false"),
    ('poll = "bus"', 'pol = "bus"', "did you mean 'poll'"),
])
def test_a_wrong_key_or_value_is_one_line(old: str, new: str, says: str) -> None:
    with pytest.raises(maps.MapError) as info:
        _map(MAP.replace(old, new))
    text = str(info.value)
    assert text.startswith("acme.toml: ")
    assert "\n" not in text
    assert says in text, text


def test_the_logger_polls_at_the_bus_interval_and_backs_off(tmp_path: Path) -> None:
    path = tmp_path / "acme.toml"
    path.write_text(MAP)
    db = tmp_path / "x.sqlite"
    with SimulatorProcess(["--map", str(path), "acme-psu:1", "--tcp", "127.0.0.1:0"],
                          quiet=True) as sim:
        r = run_pymb("log", "--map", str(path), "acme-psu:1", "acme-psu:2", "--tcp",
                     f"127.0.0.1:{sim.tcp_port}", "--interval", "0.2", "--timeout", "0.2",
                     "--seconds", "4", "--out", str(db), "--quiet")
    no_traceback(r)
    with sqlite3.connect(db) as con:
        rows = dict(con.execute(
            "SELECT d.name, COUNT(*) FROM samples s JOIN devices d ON d.id = s.device_id "
            "GROUP BY d.name").fetchall())
        groups = {g for (g,) in con.execute("SELECT humidity_units FROM devices")}
        said = [m for (m,) in con.execute(
            "SELECT e.message FROM events e JOIN devices d ON d.id = e.device_id "
            "WHERE d.name = 'acme-psu-2' ORDER BY e.id")]
    # every 0.2 s (the bus's), not every 30 s (the group's); "info" never polled
    assert rows.get("acme-psu-1", 0) >= 6, rows
    assert "acme-psu-2" not in rows
    assert all("info" not in g for g in groups), groups
    # two failures, then a doubling wait said by each failure; never "offline"
    assert len(said) >= 3, said
    assert not said[0].endswith(" s"), said
    assert said[1].endswith("; next try in 0.5 s"), said
    assert said[2].endswith("; next try in 1 s"), said
    assert not any("offline after" in m or "answers again" in m for m in said), said


def test_a_device_that_refuses_every_point_is_backed_off_at_once(tmp_path: Path) -> None:
    # backoff = true on a user's map: a poll the device answered with an
    # exception for every point is a no_value failure, said in one line
    # (what answered), not a crash of the bus's thread
    path, other = tmp_path / "acme.toml", tmp_path / "other.toml"
    path.write_text(MAP)
    other.write_text(MAP.replace('id = "acme-psu"', 'id = "acme-other"')
                     .replace("address = 0", "address = 900"))
    db = tmp_path / "x.sqlite"
    with SimulatorProcess(["--map", str(path), "acme-psu:1", "--tcp", "127.0.0.1:0"],
                          quiet=True) as sim:
        r = run_pymb("log", "--map", str(other), "acme-other:1", "--tcp",
                     f"127.0.0.1:{sim.tcp_port}", "--interval", "0.2", "--timeout", "0.5",
                     "--seconds", "3", "--out", str(db), "--quiet")
    no_traceback(r)
    assert r.returncode == 3, r.stderr  # a device that delivered no sample
    with sqlite3.connect(db) as con:
        samples = con.execute("SELECT COUNT(*) FROM samples").fetchone()[0]
        said = [(k, m) for k, m in con.execute(
            "SELECT e.kind, e.message FROM events e JOIN devices d ON d.id = e.device_id "
            "WHERE d.name = 'acme-other-1' ORDER BY e.id")]
    assert samples == 0
    assert said, said
    assert said[0][0] == "no_value", said
    # backed off at once: the first failure already says when it is tried again
    first = said[0][1]
    assert first.startswith("acme-other-1 supplied no value: address 1 "), said
    assert "not acme-other" in first, said
    assert first.endswith("; next try in 0.5 s"), said


def test_what_answered_a_map_device_of_no_value_is_one_phrase() -> None:
    assert mismatch(None, "acme-other", 3, 0) == (
        "address 3 refused every point of the acme-other map")
    assert mismatch(None, "hub", 3, 100) == "nothing answers at address 3"


def test_a_map_whose_groups_are_all_on_request_is_not_polled_whole(tmp_path: Path) -> None:
    # every group read on request: nothing for the logger to poll, said in one
    # line (not a poll of every point, as a map without groups is read)
    text = MAP.replace('live = { interval = 30.0, poll = "bus" }\n', "").replace(
        'group = "live"', 'group = "info"')
    m = _map(text)
    with pytest.raises(InvalidArgument, match="every group of acme-psu is read on request"):
        DeviceConfig(MapText(m, text), 1)
    path = tmp_path / "acme.toml"
    path.write_text(text)
    r = run_pymb("log", "--map", str(path), "acme-psu:1", "--tcp", "127.0.0.1:9",
                 "--seconds", "1", "--out", str(tmp_path / "x.sqlite"))
    no_traceback(r)
    assert r.returncode == 2, r.stderr
    assert "every group of acme-psu is read on request" in r.stderr
