"""A broker that refuses samples (an ACL that denies the topic, a message size
limit): with MQTT 5 the refusal is in the acknowledgement, the sample stays in
the database, is said once, and goes out when the broker takes it again; with
MQTT 3.1.1 the broker cannot say so."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import pytest

pytest.register_assert_rewrite("mqtt_broker")
from conftest import run_pymb, wait_until  # noqa: E402
from mqtt_broker import Fleet, db_count, db_events, db_ids, plain_ids, stop_log  # noqa: E402

pytest_plugins = ["mqtt_broker"]  # the fixtures: fleet, mosquitto, simulator

NODE = "gw-refuse"
#: mosquitto 2.0.11 drops a client after refusing its message when max_queued_messages
#: is 0 (unlimited, as the fleet tests' brokers have it); its default is 1000
QUEUE = "max_queued_messages 1000"


def _cursor(db: Path) -> int:
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    try:
        row = con.execute("SELECT MAX(sample_id) FROM outbox").fetchone()
        return int(row[0] or 0)
    finally:
        con.close()


def test_acl_refusal_keeps_the_samples_and_sends_them_once_allowed(
        fleet: Fleet, simulator: str, tmp_path: Path) -> None:
    acl = tmp_path / "acl"
    acl.write_text("topic read pymb/#\n")  # the subscriber reads, pymb may not write
    broker = fleet.broker(extra=(QUEUE, f"acl_file {acl}"))
    sub = fleet.subscribe(broker, f"pymb/{NODE}/#")
    db = tmp_path / "log.sqlite"
    flags = ["--mqtt", broker.url, "--mqtt-node", NODE]
    # a first run: everything refused, said once, nothing acknowledged
    proc = fleet.log(simulator, db, *flags)
    wait_until(lambda: db_events(db, "refused"), "a refusal in the event log", 60)
    wait_until(lambda: db_count(db) > 300, "300 samples logged", 60)
    err = stop_log(proc)
    assert plain_ids(sub.snapshot()) == []
    said = [line for line in err.splitlines() if "the broker refused sample" in line]
    assert len(said) == 1, err
    assert "Not authorized" in said[0]
    assert f"pymb/{NODE}/coolpro-40" in said[0]
    assert "mqtt refused (Not authorized)" in err  # the final status line
    assert "the broker refuses samples (Not authorized)" in err  # the summary
    assert "nothing left to send" not in err
    assert _cursor(db) == 0  # the outbox keeps every one
    kept = db_ids(db)
    # a second run: still refused at first, then the ACL is fixed and read again
    proc = fleet.log(simulator, db, *flags)
    wait_until(lambda: len(db_events(db, "refused sample")) >= 2, "the second run's refusal", 60)
    acl.write_text("topic readwrite pymb/#\n")
    broker.reload()
    wait_until(lambda: kept <= set(plain_ids(sub.snapshot())),
               "every sample of the first run at the subscriber", 120)
    err = stop_log(proc)
    assert "the broker takes the samples it refused" in err
    assert "nothing left to send" in err
    assert db_ids(db) <= set(plain_ids(sub.snapshot()))
    assert [line for line in err.splitlines() if "the broker refused sample" in line]


def test_message_size_limit_loses_nothing_and_sends_once_raised(
        fleet: Fleet, simulator: str, tmp_path: Path) -> None:
    # a CoolPro's JSON sample is about 700 bytes: over 300, every one is too large
    broker = fleet.broker(extra=(QUEUE, "message_size_limit 300"))
    sub = fleet.subscribe(broker, f"pymb/{NODE}/#")
    db = tmp_path / "log.sqlite"
    proc = fleet.log(simulator, db, "--mqtt", broker.url, "--mqtt-node", NODE)
    wait_until(lambda: db_count(db) > 300, "300 samples logged", 60)
    wait_until(lambda: db_events(db, "message_size_limit"), "the broker's no as an event", 60)
    assert plain_ids(sub.snapshot()) == []
    assert _cursor(db) == 0
    kept = db_ids(db)
    broker.reload(extra=(QUEUE, "message_size_limit 0"))
    wait_until(lambda: kept <= set(plain_ids(sub.snapshot())),
               "every sample kept at the subscriber", 120)
    stop_log(proc)


def test_mqtt_311_cannot_tell_a_refusal(fleet: Fleet, simulator: str, tmp_path: Path) -> None:
    """What docs/fleet.md says of MQTT 3.1.1: the broker acknowledges what it drops."""
    acl = tmp_path / "acl"
    acl.write_text("topic read pymb/#\n")
    broker = fleet.broker(extra=(QUEUE, f"acl_file {acl}"))
    sub = fleet.subscribe(broker, f"pymb/{NODE}/#")
    db = tmp_path / "log.sqlite"
    proc = fleet.log(simulator, db, "--mqtt", broker.url, "--mqtt-node", NODE,
                     "--mqtt-protocol", "3.1.1")
    wait_until(lambda: db_count(db) > 100 and _cursor(db) > 100,
               "samples acknowledged", 60)
    err = stop_log(proc)
    assert plain_ids(sub.snapshot()) == []
    assert "refused" not in err


def test_a_refused_ndeath_says_the_will_is_refused_too(fleet: Fleet, simulator: str,
                                                       tmp_path: Path) -> None:
    """An ACL that lets a Sparkplug node publish everything but its NDEATH: the broker
    takes the CONNECT and drops its will without a word; the NDEATH of the clean
    end, at QoS 1, is refused in its PUBACK (MQTT 5), and the node says what that
    means: host applications never see it go offline, a crash included."""
    acl = tmp_path / "acl"
    acl.write_text("".join(f"topic readwrite spBv1.0/plant/{kind}/#\n" for kind in
                           ("NBIRTH", "DBIRTH", "NDATA", "DDATA", "DDEATH", "NCMD")))
    broker = fleet.broker(extra=(QUEUE, f"acl_file {acl}"))
    db = tmp_path / "log.sqlite"
    proc = fleet.log(simulator, db, "--mqtt", broker.url, "--mqtt-profile", "sparkplug",
                     "--mqtt-group", "plant", "--mqtt-node", NODE)
    wait_until(lambda: db_count(db) > 100 and _cursor(db) > 50, "samples acknowledged", 60)
    err = stop_log(proc)
    said = [line for line in err.splitlines() if "NDEATH" in line]
    assert len(said) == 1, err
    assert f"spBv1.0/plant/NDEATH/{NODE}" in said[0]
    assert "Not authorized" in said[0]
    assert "will" in said[0]
    # in the event log too, though the logger's database was closed by then
    assert db_events(db, "NDEATH") == [said[0].split("mqtt: ", 1)[1]]


def test_protocol_option_is_checked(tmp_path: Path) -> None:
    toml = tmp_path / "pymb.toml"
    toml.write_text('[[bus]]\ntcp = "127.0.0.1:1502"\n[[bus.device]]\ntype = "coolpro"\n\n'
                    '[mqtt]\nurl = "mqtt://127.0.0.1:1883"\nprotocol = "4"\n')
    r = run_pymb("log", "--config", str(toml), "--out", str(tmp_path / "x.sqlite"))
    assert r.returncode == 2
    assert "MQTT protocol must be 5 or 3.1.1, got '4'" in r.stderr
    assert "Traceback" not in r.stderr
    r = run_pymb("log", "--tcp", "127.0.0.1:1502", "--device", "coolpro:40", "--out",
                 str(tmp_path / "x.sqlite"), "--mqtt", "mqtt://127.0.0.1:1883",
                 "--mqtt-protocol", "4")
    assert r.returncode == 2
    assert "--mqtt-protocol" in r.stderr
