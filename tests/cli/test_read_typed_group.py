"""``pymb read``/``pymb watch`` of one group of the CoolPro's or the hub's
map with ``--group``, a request group (``poll = "request"``, never polled)
included, as docs/map-format.md says: shown as any map device's points.
Real ``pymb`` processes against ``pymb simulate`` on a pty."""

from __future__ import annotations

import json
from collections.abc import Iterator

import pytest
from conftest import run_pymb

from pymb.sim import SimulatorProcess


@pytest.fixture(scope="module")
def sim() -> Iterator[SimulatorProcess]:
    with SimulatorProcess(["coolpro", "hub:250"], quiet=True) as s:
        yield s


def test_the_coolpros_identity_group_is_read_on_request(sim: SimulatorProcess) -> None:
    r = run_pymb("read", "coolpro", "--group", "identity", "--port", sim.port)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert [ln.split()[0] for ln in lines] == ["serial_number", "hardware_revision",
                                               "firmware_major", "firmware_minor",
                                               "firmware_patch", "manufactured"]
    assert lines[0].split() == ["serial_number", "12345"]
    r = run_pymb("read", "coolpro:40", "--group", "config", "--json", "--port", sim.port)
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    assert doc["device"] == "coolpro"
    assert doc["address"] == 40
    assert doc["values"] == {"address": 40, "baud_rate_index": 0, "reset": 0}
    assert doc["states"]["address"] == "value"


def test_a_hubs_group_and_a_watch_of_a_request_group(sim: SimulatorProcess) -> None:
    r = run_pymb("read", "hub", "--address", "250", "--group", "sweep", "--port", sim.port)
    assert r.returncode == 0, r.stderr
    names = [ln.split()[0] for ln in r.stdout.splitlines()]
    assert names[0] == "temperature_c[1]"
    assert len(names) == 700
    r = run_pymb("watch", "coolpro", "--group", "identity", "--count", "1", "--port", sim.port)
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines()[0].startswith("coolpro:40  1 reads ")
    assert r.stdout.splitlines()[1].split() == ["serial_number", "12345"]


def test_a_mistake_is_one_line(sim: SimulatorProcess) -> None:
    r = run_pymb("read", "coolpro", "--group", "idnetity", "--port", sim.port)
    assert (r.returncode, r.stdout) == (2, "")
    assert r.stderr == "pymb read: coolpro has no group 'idnetity'; did you mean 'identity'?\n"
    r = run_pymb("read", "coolpro", "--group", "identity", "--channels", "5", "--port", sim.port)
    assert (r.returncode, r.stderr) == (2, "pymb read: --channels is for a hub\n")
    r = run_pymb("watch", "hub:250", "--group", "sweep", "--block", "all", "--port", sim.port)
    assert (r.returncode, r.stderr) == (2, "pymb watch: --block and --show choose a hub's blocks "
                                           "and channels; --group shows every point of its "
                                           "group\n")
