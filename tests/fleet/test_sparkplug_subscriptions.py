"""Sparkplug B against a broker that refuses some of the node's subscriptions
(its SUBACK's reason code says so): the primary host's STATE, the node's NCMD.
mosquitto's acl_file grants every subscription and filters what it delivers;
its dynamic security plugin (Debian's mosquitto package has it) refuses a
subscription its role denies."""

from __future__ import annotations

import glob
import json
from pathlib import Path
from typing import Any

import pytest

pytest.register_assert_rewrite("mqtt_broker")
from conftest import wait_until  # noqa: E402
from mqtt_broker import Fleet, db_count, db_events, db_ids, stop_log  # noqa: E402

pytest_plugins = ["mqtt_broker"]  # the fixtures: fleet, mosquitto, simulator

NODE = "gw-acl"
GROUP = "plant"


def _denying(tmp_path: Path, *patterns: str) -> tuple[str, ...]:
    """mosquitto's configuration lines for its dynamic security plugin, which lets
    anonymous clients do anything but subscribe to ``patterns``."""
    found = sorted(glob.glob("/usr/lib/*/mosquitto_dynamic_security.so")
                   + glob.glob("/usr/lib/mosquitto_dynamic_security.so"))
    if not found:
        pytest.fail("mosquitto's dynamic security plugin is missing: .ci/setup installs "
                    "mosquitto")
    conf = tmp_path / "dynsec.json"
    allow = {"publishClientSend": True, "publishClientReceive": True, "subscribe": True,
             "unsubscribe": True}
    acls = [{"acltype": "subscribePattern", "topic": t, "priority": 0, "allow": False}
            for t in patterns]
    conf.write_text(json.dumps({
        "defaultACLAccess": allow, "clients": [],
        "groups": [{"groupname": "anon", "roles": [{"rolename": "deny"}], "clients": []}],
        "roles": [{"rolename": "deny", "acls": acls}], "anonymousGroup": "anon"}))
    return (f"plugin {found[0]}", f"plugin_opt_config_file {conf}")


def test_a_refused_subscription_to_the_primary_hosts_state_is_said(
        fleet: Fleet, simulator: str, tmp_path: Path) -> None:
    """The node may publish and read its NCMD, not the STATE topic: it would wait for
    the primary host for ever; it says once why (the broker's reason, the topic)."""
    broker = fleet.broker(extra=_denying(tmp_path, "spBv1.0/STATE/#"))
    db = tmp_path / "log.sqlite"
    proc = fleet.log(simulator, db, "--mqtt", broker.url, "--mqtt-profile", "sparkplug",
                     "--mqtt-group", GROUP, "--mqtt-node", NODE, "--mqtt-primary-host", "scada")
    wait_until(lambda: db_events(db, "connected to"), "pymb connected", 30)
    wait_until(lambda: db_count(db) > 50, "50 samples logged", 30)
    wait_until(lambda: db_events(db, "spBv1.0/STATE/scada"), "the refusal said", 15)
    err = stop_log(proc)
    said = db_events(db, "spBv1.0/STATE/scada")
    print(said, err)
    assert len(said) == 1
    assert "Not authorized" in said[0]
    assert "spBv1.0/STATE/scada" in err


def test_a_refused_ncmd_subscription_is_said_once_and_the_data_flow(
        fleet: Fleet, simulator: str, sparkplug_pb: Any, tmp_path: Path) -> None:
    """The NCMD subscription refused: said once (not at each batch, whose SUBSCRIBE
    to it is refused too, and still acknowledges the batch), every sample arrives."""
    broker = fleet.broker(extra=_denying(tmp_path, f"spBv1.0/{GROUP}/NCMD/#"))
    sub = fleet.subscribe(broker, f"spBv1.0/{GROUP}/+/{NODE}/#")
    db = tmp_path / "log.sqlite"
    proc = fleet.log(simulator, db, "--mqtt", broker.url, "--mqtt-profile", "sparkplug",
                     "--mqtt-group", GROUP, "--mqtt-node", NODE)
    wait_until(lambda: db_count(db) > 300, "300 samples logged", 30)
    err = stop_log(proc)
    said = db_events(db, f"spBv1.0/{GROUP}/NCMD/{NODE}")
    assert len(said) == 1, said
    assert "Not authorized" in said[0]
    assert "Rebirth" in said[0]
    assert "nothing left to send" in err
    got, aliases = set(), {}
    for topic, payload in sub.snapshot():
        p = sparkplug_pb.FromString(payload)
        if topic.split("/")[2] == "DBIRTH":
            aliases = {m.alias: m.name for m in p.metrics}
        elif topic.split("/")[2] == "DDATA":
            got |= {m.long_value for m in p.metrics if aliases[m.alias] == "sample"}
    assert db_ids(db) <= got
