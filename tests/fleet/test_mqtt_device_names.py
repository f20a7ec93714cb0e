"""A device's name is a level of its MQTT topics (``{prefix}/{node}/{device}``,
``spBv1.0/{group}/DDATA/{node}/{device}``): ``pymb log --mqtt`` refuses, before
it makes anything, a name that would publish where ``pymb collect`` (or any
subscriber to ``{prefix}/+/+``) never looks, or where the broker refuses to."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import run_pymb

from pymb.errors import InvalidArgument
from pymb.fleet.config import MqttConfig


@pytest.mark.parametrize(("name", "why"), [
    ("a/b", "cannot be a level of an MQTT topic"),
    ("x+y", "cannot be a level of an MQTT topic"),
    ("tank#2", "cannot be a level of an MQTT topic"),
    ("status", "is the node's own topic pymb/gw1/status"),
    ("set", "is the node's own topic pymb/gw1/set"),
])
def test_a_device_name_that_is_no_topic_level_is_refused(name: str, why: str,
                                                         tmp_path: Path) -> None:
    out = tmp_path / "log.sqlite"
    r = run_pymb("log", "--tcp", "127.0.0.1:1", "--device", f"coolpro:1,name={name}",
                 "--out", str(out), "--mqtt", "mqtt://127.0.0.1:1", "--mqtt-node", "gw1",
                 "--seconds", "1", timeout=60)
    assert r.returncode == 2, r.stderr
    assert r.stderr.strip().splitlines() == [
        f"pymb log: device name {name!r} {why}" + (
            ": choose another name for --mqtt" if "own topic" in why
            else ": use a name without '/', '+' or '#' for --mqtt")]
    assert not out.exists()


def test_sparkplug_has_no_node_topics_of_those_names() -> None:
    sparkplug = MqttConfig("mqtt://127.0.0.1", profile="sparkplug", node="gw1")
    for name in ("status", "set"):
        sparkplug.check_device(name)
    with pytest.raises(InvalidArgument, match="cannot be a level"):
        sparkplug.check_device("a/b")
