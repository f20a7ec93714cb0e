"""Fleet: every logged sample reaches a real mosquitto, through outages.

The broker is Debian's mosquitto on a free loopback port (tests/mqtt_broker.py);
pymb log runs as a child process against a simulated CoolPro on Modbus TCP; a
paho subscriber with a persistent session records what arrives. At the end the
set of sample ids received must equal the set in the database; duplicates are
counted and reported (at least once, never lost).
"""

from __future__ import annotations

import contextlib
import json
import signal
import sqlite3
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

pytest.register_assert_rewrite("mqtt_broker")
from conftest import run_pymb, wait_until  # noqa: E402
from docblocks import assert_shaped, claim_one  # noqa: E402
from mqtt_broker import (  # noqa: E402
    Fleet,
    Subscriber,
    db_count,
    db_ids,
    duplicates,
    paho,
    plain_ids,
    restart_broker_mid_run,
    stop_log,
)

from pymb.fleet.broker import Certificates, Mosquitto  # noqa: E402

pytest_plugins = ["mqtt_broker"]  # the fixtures: fleet, mosquitto, simulator, certificates, ...
NODE = "gw-test"
GROUP = "plant"

Ids = Callable[[list[tuple[str, bytes]]], list[int]]  # the sample ids in what a subscriber got


def _plain(broker: Mosquitto, node: str = NODE) -> list[str]:
    """pymb log's flags for the plain profile to ``broker``."""
    return ["--mqtt", broker.url, "--mqtt-node", node]


def _sparkplug(broker: Mosquitto) -> list[str]:
    """pymb log's flags for Sparkplug B to ``broker`` (group GROUP, node NODE)."""
    return ["--mqtt", broker.url, "--mqtt-profile", "sparkplug", "--mqtt-group", GROUP,
            "--mqtt-node", NODE]


def _all_arrived(sub: Subscriber, db: Path, ids: Ids = plain_ids) -> set[int]:
    """Wait until every sample id of the database has reached ``sub``; the ids."""
    want = db_ids(db)
    wait_until(lambda: set(ids(sub.snapshot())) >= want,
               f"all {len(want)} samples of the database at the subscriber", 30)
    return want


def _nothing_lost(what: str, sub: Subscriber, db: Path, ids: Ids = plain_ids,
                  killed: int = 0) -> None:
    """Every sample of the database reached ``sub``, and no other but those a
    kill took back (published from the batch it lost: ids up to ``killed``);
    the count of duplicates is reported (at least once, never lost)."""
    want = _all_arrived(sub, db, ids)
    got = ids(sub.snapshot())
    print(f"\n{what}: {len(want)} samples in the database, {len(set(got))} distinct "
          f"received, {duplicates(got)} duplicates")
    assert set(got) >= want
    assert all(i <= killed for i in set(got) - want), sorted(set(got) - want)[:5]


def _rebirth(sub: Subscriber, pb: Any, qos: int = 1) -> None:
    """Publish the node's Rebirth command (NCMD ``Node Control/Rebirth`` = true)."""
    cmd = pb()
    cmd.timestamp = int(time.time() * 1000)
    c = cmd.metrics.add()
    c.name, c.datatype, c.boolean_value = "Node Control/Rebirth", 11, True
    sub.client.publish(f"spBv1.0/{GROUP}/NCMD/{NODE}", cmd.SerializeToString(), qos=qos)


def test_broker_restart_mid_run_loses_nothing(fleet: Fleet, simulator: str,
                                              tmp_path: Path) -> None:
    broker = fleet.broker()
    sub = fleet.subscribe(broker, f"pymb/{NODE}/#")
    db = tmp_path / "log.sqlite"
    proc = fleet.log(simulator, db, *_plain(broker))
    restart_broker_mid_run(broker, sub, db)
    err = stop_log(proc)
    _nothing_lost("broker restart", sub, db)
    want = db_ids(db)
    assert "nothing left to send" in err
    # the retained status: online while connected, offline after the clean end
    status = [p for t, p in sub.snapshot() if t.endswith("/status")]
    assert status[0] == b"online"
    assert status[-1] == b"offline"
    con = sqlite3.connect(db)
    assert con.execute("SELECT sample_id FROM outbox").fetchone()[0] == max(want)
    # the connection's story is in the event log, for services run with --quiet
    story = [m for (m,) in con.execute("SELECT message FROM event_log WHERE kind = 'mqtt'")]
    con.close()
    assert story[0].startswith("connected to mqtt://127.0.0.1")
    assert any(m.startswith("lost the connection") for m in story)
    assert story[-1].startswith("connected to")
    # and on stderr (not a terminal) as docs/board.md shows it in the journal
    block = claim_one("docs/board.md", "text", how="compare", contains="lost the connection")
    lost = [line.replace(f"/{NODE}:", "/board-7:") for line in err.splitlines()
            if "lost the connection" in line]
    assert lost, err
    assert_shaped(block, lost[:1])


def test_broker_stalled_3s_loses_nothing(fleet: Fleet, simulator: str, tmp_path: Path) -> None:
    broker = fleet.broker()
    sub = fleet.subscribe(broker, f"pymb/{NODE}/#")
    db = tmp_path / "log.sqlite"
    proc = fleet.log(simulator, db, *_plain(broker))
    wait_until(lambda: len(plain_ids(sub.snapshot())) >= 50, "50 samples live", 30)
    broker.pause()
    t0 = time.monotonic()
    before = db_count(db)
    try:
        wait_until(lambda: time.monotonic() - t0 >= 3.0 and db_count(db) > before + 50,
                   "3 s of stall with samples logged", 30)
    finally:
        broker.resume()
    wait_until(lambda: max(plain_ids(sub.snapshot())) > before + 50, "samples after the stall", 30)
    stop_log(proc)
    _nothing_lost("broker stalled 3 s", sub, db)


def test_pymb_sigkilled_and_restarted_loses_nothing(fleet: Fleet, simulator: str,
                                                     tmp_path: Path) -> None:
    broker = fleet.broker()
    sub = fleet.subscribe(broker, f"pymb/{NODE}/#")
    db = tmp_path / "log.sqlite"
    proc = fleet.log(simulator, db, *_plain(broker))
    wait_until(lambda: len(plain_ids(sub.snapshot())) >= 200, "200 samples live", 30)
    proc.send_signal(signal.SIGKILL)
    proc.wait(10)
    # the will: the broker says offline for the killed pymb
    wait_until(lambda: sub.snapshot()[-1] == (f"pymb/{NODE}/status", b"offline"),
               "the last will (offline)", 30)
    killed = max(plain_ids(sub.snapshot()))
    proc = fleet.log(simulator, db, *_plain(broker))
    wait_until(lambda: sum(1 for i in set(plain_ids(sub.snapshot())) if i > killed) >= 50,
               "samples of the second run", 30)
    stop_log(proc)
    _nothing_lost("pymb SIGKILLed and restarted", sub, db, killed=killed)


#: The plain payload's keys, in order: the sample's --format jsonl object plus
#: ``sample`` (README, "Profile plain"); a hub's has states and unsupported instead
#: of status_flags.
PLAIN_KEYS = ["time_utc", "time", "monotonic", "bus", "device", "type", "address", "sample",
              "values"]


def test_plain_payload(fleet: Fleet, simulator: str, tmp_path: Path) -> None:
    broker = fleet.broker()
    sub = fleet.subscribe(broker, "plant/#")
    db = tmp_path / "log.sqlite"
    proc = fleet.log(simulator, db, *_plain(broker, "n1"), "--mqtt-prefix", "plant",
                     seconds=1.5)
    proc.communicate(timeout=60)
    assert proc.returncode == 0
    _all_arrived(sub, db)
    data = [(t, json.loads(p)) for t, p in sub.snapshot() if not t.endswith("/status")]
    t, first = data[0]
    assert t == "plant/n1/coolpro-40"
    assert list(first) == [*PLAIN_KEYS, "status_flags"]
    assert first["device"] == "coolpro-40"
    assert first["type"] == "coolpro"
    assert first["address"] == 40
    assert first["time"].endswith("Z")
    con = sqlite3.connect(db)
    row = con.execute("SELECT s.time_utc, s.monotonic, c.output_voltage_v, c.status "
                      "FROM samples s JOIN coolpro c ON c.sample_id = s.id WHERE s.id = ?",
                      (first["sample"],)).fetchone()
    con.close()
    assert (first["time_utc"], first["monotonic"]) == row[:2]
    assert first["values"]["output_voltage_v"] == row[2]
    assert first["values"]["status"] == row[3]
    assert isinstance(first["status_flags"], list)
    # docs/fleet.md's example has the same keys in the same order
    example = claim_one("docs/fleet.md", "text", how="compare",
                        contains="pymb/gw1/coolpro-40 {").text.strip()
    top = __import__("re").sub(r'"values":\{[^}]*\}', '"values":0', example)
    assert __import__("re").findall(r'"(\w+)":', top) == [*PLAIN_KEYS, "status_flags"]


def test_tls_with_client_certificate_and_password(fleet: Fleet, simulator: str,
                                                  certificates: Certificates,
                                                  tmp_path: Path) -> None:
    certs: Certificates = certificates
    broker = fleet.broker(tls=certs, require_client_cert=True,
                          users={"gw": "s3cret pass", "test": "t"})
    sub = fleet.subscribe(broker, "pymb/#", tls=certs, user=("test", "t"))
    pw = tmp_path / "pw"
    pw.write_text("s3cret pass\n")
    db = tmp_path / "log.sqlite"
    tls = ["--mqtt-ca", certs.ca, "--mqtt-cert", certs.client_cert,
           "--mqtt-key", certs.client_key]
    # Each run is stopped (SIGTERM) once what it is there to show has happened,
    # so the drain on stopping has a few samples to send however slow the TLS
    # handshakes are on a loaded machine.
    pace = ("--interval", "0.05")

    def until(proc: Any, pred: Any, what: str) -> str:
        wait_until(pred, what, 60)
        return stop_log(proc)

    def from_node(node: str) -> int:
        return sum(t.startswith(f"pymb/{node}/") and not t.endswith("/status")
                   for t, _ in sub.snapshot())

    proc = fleet.log(simulator, db, *_plain(broker), *tls, "--mqtt-user", "gw",
                     "--mqtt-password-file", str(pw), *pace)
    err = until(proc, lambda: from_node(NODE) >= 10, "10 samples over TLS")
    assert "nothing left to send" in err, err
    assert _all_arrived(sub, db)
    # the password from the environment instead of a file
    db2 = tmp_path / "env.sqlite"
    proc = fleet.log(simulator, db2, *_plain(broker, "n2"), *tls, "--mqtt-user", "gw", *pace,
                     env={"PYMB_MQTT_PASSWORD": "s3cret pass"})
    err = until(proc, lambda: from_node("n2") >= 5, "5 samples with the password from $ENV")
    assert "nothing left to send" in err, err
    # a wrong password: refused, nothing lost (kept for the next run)
    db3 = tmp_path / "bad.sqlite"
    proc = fleet.log(simulator, db3, *_plain(broker, "n3"), *tls, "--mqtt-user", "gw", *pace,
                     env={"PYMB_MQTT_PASSWORD": "wrong"})

    def refused() -> bool:
        try:
            with contextlib.closing(sqlite3.connect(f"file:{db3}?mode=ro", uri=True)) as con:
                return bool(con.execute(
                    "SELECT COUNT(*) FROM event_log WHERE kind = 'mqtt' AND message LIKE "
                    "'%refused%'").fetchone()[0]) and db_count(db3) > 0
        except sqlite3.Error:
            return False  # not made yet

    err = until(proc, refused, "the broker's refusal in the event log")
    assert from_node("n3") == 0
    assert "not yet acknowledged" in err, err
    assert "0 samples acknowledged" in err, err
    con = sqlite3.connect(db3)
    story = [m for (m,) in con.execute("SELECT message FROM event_log WHERE kind = 'mqtt'")]
    con.close()
    assert story, story
    assert "refused" in story[0], story
    assert "authori" in story[0].lower(), story


def test_tls_verifies_the_broker(fleet: Fleet, simulator: str, certificates: Certificates,
                                 tmp_path: Path) -> None:
    """A CA that did not sign the broker's certificate: no connection, nothing sent."""
    from pymb.fleet.broker import make_certificates
    other = make_certificates(tmp_path / "other")
    broker = fleet.broker(tls=certificates)
    db = tmp_path / "log.sqlite"
    proc = fleet.log(simulator, db, "--mqtt", broker.url, "--mqtt-ca", other.ca, seconds=1.0)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    assert "0 samples acknowledged" in err


def _acknowledged(db: Path) -> Callable[[], bool]:
    """True once the forwarder's cursor in ``db`` has moved."""
    def moved() -> bool:
        try:
            with contextlib.closing(sqlite3.connect(f"file:{db}?mode=ro", uri=True)) as con:
                return bool(con.execute("SELECT MAX(sample_id) FROM outbox").fetchone()[0])
        except sqlite3.Error:
            return False  # not made yet
    return moved


def _logged_past(db: Path, count: int) -> Callable[[], bool]:
    """True once ``db`` holds more than ``count`` samples."""
    return lambda: db_count(db) > count


def test_drain_on_stopping_is_an_option(fleet: Fleet, simulator: str, tmp_path: Path) -> None:
    """A clean stop keeps sending what is left for --mqtt-drain seconds (the TOML's
    ``drain``; 5 by default), no longer: with the broker stalled (SIGSTOP) nothing
    can be acknowledged, so each run waits out its whole drain, then ends and says
    what is left for the next run."""
    from pymb.fleet.config import MqttConfig
    assert MqttConfig("mqtt://127.0.0.1").drain == 5.0
    broker = fleet.broker()
    cfg = tmp_path / "pymb.toml"
    took = {}
    for name, how in (("flag", ["--mqtt-drain", "0"]), ("toml", ["--config", str(cfg)])):
        db = tmp_path / f"{name}.sqlite"
        cfg.write_text(f'[output]\npath = "{db}"\ncommit_interval_s = 1\n'  # watched
                       f'[mqtt]\nurl = "{broker.url}"\n'
                       f'node = "{NODE}"\ndrain = 6\n'
                       f'[[bus]]\ntcp = "{simulator}"\ninterval = 0.01\n'
                       '[[bus.device]]\ntype = "coolpro"\n')
        proc = (fleet.log(simulator, db, *_plain(broker), *how) if name == "flag"
                else fleet.pymb("log", *how))
        wait_until(_acknowledged(db), "a first acknowledgement", 30)
        broker.pause()
        try:
            before = db_count(db)
            wait_until(_logged_past(db, before + 20), "samples logged the broker cannot take", 30)
            t0 = time.monotonic()
            err = stop_log(proc, timeout=60)
            took[name] = time.monotonic() - t0
        finally:
            broker.resume()
        assert "not yet acknowledged" in err, err
        assert "kept in the database" in err, err
    print(f"\nstopping with the broker stalled: drain 0 took {took['flag']:.1f} s, "
          f"drain 6 took {took['toml']:.1f} s")
    assert took["toml"] >= 6.0
    assert took["flag"] + 3.0 < took["toml"]


@pytest.mark.parametrize(("argv", "message"), [
    (["--mqtt", "http://x"], "bad MQTT URL"),
    (["--mqtt", "mqtt://u:p@host"], "no user or password in the MQTT URL"),
    (["--mqtt", "mqtt://host", "--mqtt-ca", "/etc/hostname"], "need an mqtts:// URL"),
    (["--mqtt", "mqtts://host", "--mqtt-cert", "/etc/hostname"], "needs both"),
    (["--mqtt", "mqtts://host", "--mqtt-ca", "/nonexistent"], "cannot be read"),
    (["--mqtt", "mqtt://host", "--mqtt-node", "a/b"], "without '/'"),
    (["--mqtt-node", "x"], "need --mqtt URL"),
    (["--mqtt", "mqtt://host", "--format", "csv", "--out", "-"], "use --format sqlite"),
    (["--mqtt", "mqtt://host", "--mqtt-primary-host", "scada"], "needs --mqtt-profile sparkplug"),
    (["--mqtt", "mqtt://host", "--mqtt-profile", "sparkplug", "--mqtt-primary-host", "a/b"],
     "without '/'"),
    (["--mqtt", "mqtt://host", "--mqtt-drain", "soon"], "--mqtt-drain needs a number"),
    (["--mqtt", "mqtt://host", "--mqtt-drain=-1"], "drain must be 0..3600 seconds"),
    (["--mqtt", "mqtt://host", "--mqtt-drain", "nan"], "drain must be 0..3600 seconds"),
])
def test_bad_mqtt_options_are_one_line_errors(argv: list[str], message: str,
                                              tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                              ) -> None:
    monkeypatch.chdir(tmp_path)
    r = run_pymb("log", "--tcp", "127.0.0.1:1", "--device", "coolpro", *argv, timeout=60)
    assert r.returncode == 2, r.stderr
    assert message in r.stderr
    assert "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def test_toml_mqtt_table(fleet: Fleet, simulator: str, tmp_path: Path) -> None:
    broker = fleet.broker()
    sub = fleet.subscribe(broker, "site/#")
    db = tmp_path / "log.sqlite"
    cfg = tmp_path / "pymb.toml"
    cfg.write_text(f"""
[output]
path = "{db}"
[mqtt]
url = "{broker.url}"
prefix = "site"
node = "toml-node"
[[bus]]
tcp = "{simulator}"
interval = 0.01
[[bus.device]]
type = "coolpro"
address = 40
""")
    r = run_pymb("log", "--config", str(cfg), "--seconds", "1", timeout=60)
    assert r.returncode == 0, r.stderr
    _all_arrived(sub, db)
    assert all(t.startswith("site/toml-node/") for t, _ in sub.snapshot())
    for bad, says in (('prefix = 3', "prefix has the wrong type"),
                      ('drain = "5 s"', "drain has the wrong type"),
                      ('drain = -1', "drain must be 0..3600 seconds")):
        cfg.write_text(cfg.read_text().replace('prefix = "site"', bad))
        r = run_pymb("log", "--config", str(cfg), "--seconds", "1", timeout=60)
        assert r.returncode == 2, r.stderr
        assert says in r.stderr, r.stderr
        cfg.write_text(cfg.read_text().replace(bad, 'prefix = "site"'))


def test_trim_records_unsent_samples(tmp_path: Path) -> None:
    """The age limit never deletes samples not yet forwarded (their age is
    what a clock said, which may have been wrong); once sent, they go."""
    from pymb.devices import decode_hub
    from pymb.store import DeviceInfo, Outbox, Sample, SqliteSink

    regs = __import__("array").array("H", [0] * 700)
    dev = DeviceInfo("b", "p", "hub", 1, "hub-1")
    db = tmp_path / "t.sqlite"
    sink = SqliteSink(db, max_age=100.0)
    now = time.time()
    for i in range(30):
        sink.write(Sample(dev, now - 300 + i, float(i), decode_hub(regs)))
    sink.commit()
    src = Outbox(str(db))
    src.set_cursor("dest", 10)  # 10 sent; 20 old ones not yet
    for i in range(5):
        sink.write(Sample(dev, now - 5 + i, float(i), decode_hub(regs)))
    sink.commit()
    assert sink.trim() == 10
    assert sink.db.execute("SELECT MIN(id) FROM samples").fetchone() == (11,)
    assert sink.db.execute("SELECT * FROM events").fetchall() == []  # nothing unsent went
    src.set_cursor("dest", 30)  # sent now
    assert sink.trim() == 20
    assert sink.db.execute("SELECT * FROM events").fetchall() == []
    src.close()
    sink.close()


# -- Sparkplug B -------------------------------------------------------------------------


def _sp(pb: Any, messages: list[tuple[str, bytes]]) -> list[tuple[str, Any]]:
    """(message type, decoded Payload) of the node's messages, in order of arrival;
    the type is NBIRTH, DDATA, ... with the device for the device messages."""
    out = []
    for topic, payload in messages:
        parts = topic.split("/")
        assert parts[0] == "spBv1.0", topic
        assert parts[1] == GROUP, topic
        assert parts[3] == NODE, topic
        kind = parts[2] if len(parts) == 4 else f"{parts[2]}/{parts[4]}"
        out.append((kind, pb.FromString(payload)))
    return out


def _sample_ids(pb: Any, messages: list[tuple[str, bytes]]) -> list[int]:
    """The ``sample`` metric of every DDATA, through the aliases of the last DBIRTH."""
    aliases: dict[int, str] = {}
    ids = []
    for kind, p in _sp(pb, messages):
        if kind.startswith("DBIRTH"):
            aliases = {m.alias: m.name for m in p.metrics}
        elif kind.startswith("DDATA"):
            ids += [m.long_value for m in p.metrics if aliases[m.alias] == "sample"]
    return ids


def _historical_ids(pb: Any, messages: list[tuple[str, bytes]]) -> set[int]:
    """The ``sample`` metric of the DDATA marked is_historical."""
    aliases: dict[int, str] = {}
    ids = set()
    for kind, p in _sp(pb, messages):
        if kind.startswith("DBIRTH"):
            aliases = {m.alias: m.name for m in p.metrics}
        elif kind.startswith("DDATA"):
            ids |= {m.long_value for m in p.metrics
                    if aliases[m.alias] == "sample" and m.is_historical}
    return ids


def _metric(p: Any, name: str) -> Any:
    return next(m for m in p.metrics if m.name == name)


def test_protobuf_encoder_against_pysparkplug(sparkplug_pb: Any) -> None:
    from pymb.fleet.protobuf import DataType, Metric, command_metrics, encode_payload
    metrics = [
        Metric("bdSeq", None, DataType.INT64, 255, 1700000000123),
        Metric("Node Control/Rebirth", 1, DataType.BOOLEAN, False, 5),
        Metric("t", 300000, DataType.DOUBLE, -12.5, 2**41, True),
        Metric(None, 7, DataType.UINT32, 0xFFFFFFFF),
        Metric("s", 8, DataType.STRING, "héllo"),
        Metric("n", 9, DataType.DOUBLE, None, None, False,
               (("Quality", DataType.INT32, 0), ("state", DataType.STRING, "no_sensor"))),
        Metric("u", 10, DataType.UINT64, 2**64 - 1, 1),
        Metric("i", 11, DataType.INT64, -2, 1),
    ]
    p = sparkplug_pb.FromString(encode_payload(metrics, timestamp=1700000000999, seq=200))
    assert p.timestamp == 1700000000999
    assert p.seq == 200
    m = p.metrics
    assert (m[0].name, m[0].datatype, m[0].long_value, m[0].timestamp) == \
        ("bdSeq", 4, 255, 1700000000123)
    # Int64 in long_value as two's complement (the .proto's uint64)
    assert (m[6].datatype, m[6].long_value) == (8, 2**64 - 1)
    assert (m[7].datatype, m[7].long_value) == (4, 2**64 - 2)
    assert not m[0].HasField("alias")
    assert (m[1].alias, m[1].datatype, m[1].boolean_value) == (1, 11, False)
    assert m[1].HasField("boolean_value")
    assert (m[2].double_value, m[2].is_historical, m[2].timestamp, m[2].alias) == \
        (-12.5, True, 2**41, 300000)
    assert not m[3].HasField("name")
    assert m[3].int_value == 0xFFFFFFFF
    assert m[4].string_value == "héllo"
    assert m[5].is_null
    assert not m[5].HasField("double_value")
    assert list(m[5].properties.keys) == ["Quality", "state"]
    assert m[5].properties.values[1].string_value == "no_sensor"
    # and a command written by the other implementation is read back
    cmd = sparkplug_pb()
    c = cmd.metrics.add()
    c.name, c.datatype, c.boolean_value = "Node Control/Rebirth", 11, True
    assert command_metrics(cmd.SerializeToString()) == [("Node Control/Rebirth", None, True)]


def test_sparkplug_births_seq_rebirth_and_ndeath_on_sigkill(fleet: Fleet, simulator: str,
                                                            sparkplug_pb: Any,
                                                            tmp_path: Path) -> None:
    pb = sparkplug_pb
    broker = fleet.broker()
    sub = fleet.subscribe(broker, f"spBv1.0/{GROUP}/+/{NODE}/#")
    db = tmp_path / "log.sqlite"
    proc = fleet.log(simulator, db, *_sparkplug(broker))
    # seq wraps: more than 256 messages
    wait_until(lambda: len(sub.snapshot()) > 300, "300 Sparkplug messages", 60)
    msgs = _sp(pb, sub.snapshot())
    kind, nbirth = msgs[0]
    assert kind == "NBIRTH"
    assert nbirth.seq == 0
    bd = _metric(nbirth, "bdSeq")
    assert bd.datatype == 4  # Int64, as Sparkplug 3.0 says for the will and NBIRTH
    bd_seq = bd.long_value
    rebirth = _metric(nbirth, "Node Control/Rebirth")
    assert rebirth.datatype == 11
    assert rebirth.boolean_value is False
    assert msgs[1][0] == "DBIRTH/coolpro-40"
    dbirth = msgs[1][1]
    declared = {m.alias: m for m in dbirth.metrics}
    assert all(m.name and m.HasField("alias") for m in dbirth.metrics)
    assert {m.name for m in dbirth.metrics} >= {"sample", "output_voltage_v", "status"}
    seqs = [p.seq for _, p in msgs]
    assert seqs == [i % 256 for i in range(len(seqs))], "seq 0..255, wrapping"
    historical = []
    node = {m.alias for m in nbirth.metrics}
    for kind, p in msgs[2:]:
        if kind == "NDATA":  # the node's backlog changed (a loaded machine: at most every 5 s)
            assert p.metrics
            assert all(m.alias in node for m in p.metrics)
            continue
        assert kind == "DDATA/coolpro-40"
        for m in p.metrics:
            assert not m.name
            assert m.alias in declared
            assert m.datatype == declared[m.alias].datatype
        flags = {m.is_historical for m in p.metrics}
        assert len(flags) == 1, "one sample, one kind"
        historical.append((flags.pop(), max(m.timestamp for m in p.metrics)))
    # samples written before the connection was up (a loaded machine) are the
    # backlog, marked historical (and may go after the first live ones); every
    # sample after the first live one is live
    first_live = min(t for h, t in historical if not h)
    assert all(t < first_live for h, t in historical if h)
    # a Rebirth command: new births (same bdSeq: the connection is the same)
    n = len(sub.snapshot())
    _rebirth(sub, pb, qos=0)
    wait_until(lambda: any(t.split("/")[2] == "DBIRTH" for t, _ in sub.snapshot()[n:]),
               "births after the Rebirth command", 30)
    after = _sp(pb, sub.snapshot()[n:])
    i = next(i for i, (k, _) in enumerate(after) if k == "NBIRTH")
    assert after[i][1].seq == 0
    assert _metric(after[i][1], "bdSeq").long_value == bd_seq
    assert after[i + 1][0] == "DBIRTH/coolpro-40"
    assert after[i + 1][1].seq == 1
    # SIGKILL: the broker sends the will, NDEATH with the births' bdSeq
    proc.send_signal(signal.SIGKILL)
    proc.wait(10)
    wait_until(lambda: sub.snapshot()[-1][0].split("/")[2] == "NDEATH", "the NDEATH", 30)
    kind, ndeath = _sp(pb, sub.snapshot()[-1:])[0]
    assert _metric(ndeath, "bdSeq").long_value == bd_seq
    assert _metric(ndeath, "bdSeq").datatype == 4
    assert not ndeath.HasField("seq")
    # the next run counts bdSeq on, and ends with its own NDEATH; stopped once
    # the killed run's samples have all arrived (sent again as history), so
    # its drain on stopping has only its own last few to send
    killed = db_ids(db)
    killed_top = max(_sample_ids(pb, sub.snapshot()))  # published, maybe taken back
    n = len(sub.snapshot())
    proc = fleet.log(simulator, db, *_sparkplug(broker), "--interval", "0.05")
    wait_until(lambda: len(sub.snapshot()) > n + 20
               and set(_sample_ids(pb, sub.snapshot())) >= killed,
               "the second run's messages and the killed run's samples", 60)
    stop_log(proc)
    wait_until(lambda: sub.snapshot()[-1][0].split("/")[2] == "NDEATH", "the clean NDEATH", 30)
    second = _sp(pb, sub.snapshot()[n:])
    assert second[0][0] == "NBIRTH"
    assert _metric(second[0][1], "bdSeq").long_value == (bd_seq + 1) % 256
    assert _metric(second[-1][1], "bdSeq").long_value == (bd_seq + 1) % 256
    # the samples of the killed run that were not acknowledged came again, as
    # history; how many depends on where the kill fell against the cursor's
    # last commit, so every one of them is checked, however few
    again = set(_sample_ids(pb, sub.snapshot()[n:])) & killed
    assert again <= _historical_ids(pb, sub.snapshot()[n:]), "resent samples are history"
    _nothing_lost("Sparkplug, pymb SIGKILLed and restarted", sub, db,
                  lambda m: _sample_ids(pb, m), killed=killed_top)


def test_sparkplug_bdseq_wraps_from_255_to_0(fleet: Fleet, simulator: str, sparkplug_pb: Any,
                                           tmp_path: Path) -> None:
    """bdSeq counts 0..255 across runs (kept in the file): after 255 comes 0, in the
    NBIRTH and in the NDEATH of the session."""
    pb = sparkplug_pb
    broker = fleet.broker()
    sub = fleet.subscribe(broker, f"spBv1.0/{GROUP}/+/{NODE}/#")
    db = tmp_path / "log.sqlite"
    proc = fleet.log(simulator, db, *_sparkplug(broker), seconds=1)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    con = sqlite3.connect(db)
    with con:
        assert con.execute("UPDATE fleet_state SET value = 255").rowcount == 1
    con.close()
    n = len(sub.snapshot())
    proc = fleet.log(simulator, db, *_sparkplug(broker), seconds=1)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    wait_until(lambda: sub.snapshot()[-1][0].split("/")[2] == "NDEATH", "the clean NDEATH", 30)
    run = _sp(pb, sub.snapshot()[n:])
    assert run[0][0] == "NBIRTH"
    assert run[-1][0] == "NDEATH"
    assert [_metric(p, "bdSeq").long_value for _, p in (run[0], run[-1])] == [0, 0]


def test_sparkplug_historical_replay_after_an_outage(fleet: Fleet, simulator: str,
                                                     sparkplug_pb: Any, tmp_path: Path) -> None:
    pb = sparkplug_pb
    broker = fleet.broker()
    sub = fleet.subscribe(broker, f"spBv1.0/{GROUP}/+/{NODE}/#")
    db = tmp_path / "log.sqlite"
    proc = fleet.log(simulator, db, *_sparkplug(broker))
    wait_until(lambda: len(sub.snapshot()) > 30, "30 messages live", 30)
    broker.stop()
    # published (live, from the open batch) before the broker went: not history
    down_from = max(_sample_ids(pb, sub.snapshot()))
    wait_until(lambda: db_count(db) > down_from + 100, "100 samples logged while down", 30)
    down_to = db_count(db)
    broker.start()
    wait_until(lambda: set(_sample_ids(pb, sub.snapshot())) >= set(range(1, down_to + 1)),
               "the outage's samples replayed", 60)
    # the node's backlog metric, once the replay is done: an NDATA
    def ndata_after_rebirth() -> bool:
        ks = [t.split("/")[2] for t, _ in sub.snapshot()]
        return ks.count("NBIRTH") >= 2 and "NDATA" in ks[ks.index("NBIRTH", 1):]
    wait_until(ndata_after_rebirth, "an NDATA after the second NBIRTH", 30)
    stop_log(proc)
    wait_until(lambda: sub.snapshot()[-1][0].split("/")[2] == "NDEATH", "the clean NDEATH", 30)
    msgs = _sp(pb, sub.snapshot())
    births = [i for i, (k, _) in enumerate(msgs) if k == "NBIRTH"]
    assert len(births) >= 2
    # a new session after the broker's restart: a new bdSeq, which the clean end's
    # NDEATH carries (counted per connection attempt, as Eclipse Tahu counts them:
    # the attempts while the broker was away count too)
    bd = [_metric(msgs[i][1], "bdSeq").long_value for i in births]
    assert bd[1] != bd[0]
    assert msgs[-1][0] == "NDEATH"
    assert _metric(msgs[-1][1], "bdSeq").long_value == bd[-1]
    # after the reconnection: births first, then the backlog as history
    assert msgs[births[1] + 1][0] == "DBIRTH/coolpro-40"
    aliases = {m.alias: m.name for m in msgs[births[1] + 1][1].metrics}
    historical = {m.long_value for _, p in msgs[births[1]:] for m in p.metrics
                  if m.is_historical and aliases.get(m.alias) == "sample"}
    assert set(range(down_from + 1, down_to + 1)) <= historical
    # NBIRTH declares Forwarder/Backlog (the samples not yet acknowledged: the
    # outage's, on the reconnection); NDATA says it changed, by alias, with seq
    backlog = _metric(msgs[births[1]][1], "Forwarder/Backlog")
    assert backlog.datatype == 8
    assert backlog.HasField("alias")
    assert backlog.HasField("timestamp")
    assert backlog.long_value >= down_to - down_from
    ndata_at = next(i for i, (k, _) in enumerate(msgs) if i > births[1] and k == "NDATA")
    ndata = msgs[ndata_at][1]
    assert [(m.name, m.alias) for m in ndata.metrics] == [("", backlog.alias)]
    assert ndata.metrics[0].long_value < backlog.long_value
    assert ndata.metrics[0].HasField("timestamp")
    assert ndata.HasField("timestamp")
    assert ndata.seq == (msgs[ndata_at - 1][1].seq + 1) % 256
    assert sub.flags[ndata_at] == (0, False)
    _nothing_lost("Sparkplug, broker restart", sub, db, lambda m: _sample_ids(pb, m))


def test_sparkplug_ddeath_when_a_device_stops_answering_and_dbirth_when_it_returns(
        fleet: Fleet, sparkplug_pb: Any, tmp_path: Path) -> None:
    """A device that stops answering: DDEATH (timestamp and seq, no metrics, QoS 0,
    not retained) after its last DDATA; when it answers again, a new DBIRTH before
    its next DDATA. Nothing is lost and seq stays continuous throughout."""
    from itertools import pairwise

    from pymb.fleet.health import DOWN_AFTER
    pb = sparkplug_pb
    broker = fleet.broker()
    sub = fleet.subscribe(broker, f"spBv1.0/{GROUP}/+/{NODE}/#")
    sim = fleet.simulator("coolpro")
    db = tmp_path / "log.sqlite"
    proc = fleet.log(sim.endpoint, db, *_sparkplug(broker))

    def node_messages() -> list[tuple[tuple[str, bytes], tuple[int, bool]]]:
        """What the node published (the test's own NCMD left out), with (QoS, retain)."""
        got = sub.snapshot()
        return [(m, f) for m, f in zip(got, sub.flags[:len(got)], strict=True)
                if m[0].split("/")[2] != "NCMD"]

    def kinds(start: int = 0) -> list[str]:
        return [t.split("/", 2)[2] for (t, _), _f in node_messages()[start:]]

    wait_until(lambda: kinds().count(f"DDATA/{NODE}/coolpro-40") >= 20, "20 DDATA", 30)
    port = sim.tcp_port
    sim.stop()
    stopped_at = time.time()
    wait_until(lambda: f"DDEATH/{NODE}/coolpro-40" in kinds(), "the DDEATH", 60)
    died = kinds().index(f"DDEATH/{NODE}/coolpro-40")
    # a Rebirth while it is down: its DBIRTH (its metrics declared), then its DDEATH
    _rebirth(sub, pb)
    births = [f"NBIRTH/{NODE}", f"DBIRTH/{NODE}/coolpro-40", f"DDEATH/{NODE}/coolpro-40"]

    def reborn() -> int | None:
        """Where the Rebirth's NBIRTH is, once it and the two after it came
        (an NDATA of the node's backlog may come before it)."""
        k = kinds()
        at = next((i for i in range(died + 1, len(k)) if k[i] == births[0]), None)
        return at if at is not None and k[at:at + 3] == births else None

    at = wait_until(reborn, lambda: "NBIRTH, DBIRTH and DDEATH after the Rebirth; after the "
                    f"first DDEATH came {kinds(died + 1)}", 30)
    assert at is not None
    first_death, died = died, at + 2
    fleet.simulator("coolpro", port=port)
    wait_until(lambda: f"DDATA/{NODE}/coolpro-40" in kinds(died),
               "DDATA after the device answers again", 60)
    stop_log(proc)
    wait_until(lambda: kinds()[-1] == "NDEATH/" + NODE, "the clean NDEATH", 30)
    published = node_messages()
    msgs = _sp(pb, [m for m, _ in published])
    flags = [f for _, f in published]
    # the DDEATHs: QoS 0, not retained, a timestamp (publication time) and seq, no metric
    for at in (first_death, died):
        kind, ddeath = msgs[at]
        assert kind == "DDEATH/coolpro-40"
        assert flags[at] == (0, False)
        assert ddeath.HasField("timestamp")
        assert ddeath.HasField("seq")
        assert not ddeath.metrics
        assert stopped_at * 1000 - 1000 <= ddeath.timestamp <= time.time() * 1000
    # it comes after every DDATA of the samples taken before the device stopped
    con = sqlite3.connect(db)
    last_before = con.execute("SELECT MAX(id) FROM samples WHERE time_utc < ?",
                              (stopped_at,)).fetchone()[0]
    faults = con.execute("SELECT COUNT(*) FROM events WHERE kind IN "
                         "('timeout', 'connection', 'protocol', 'error')").fetchone()[0]
    con.close()
    assert faults >= DOWN_AFTER
    before = _sample_ids(pb, [m for m, _ in published[:first_death]])
    assert max(before) == last_before
    # then a DBIRTH (every metric, named and aliased) before the next DDATA
    after = [(k, p) for k, p in msgs[died + 1:] if k not in ("NDEATH", "NDATA")]
    assert after[0][0] == "DBIRTH/coolpro-40", [k for k, _ in after[:3]]
    dbirth = after[0][1]
    assert {m.name for m in dbirth.metrics} >= {"sample", "output_voltage_v", "status"}
    assert all(m.HasField("alias") for m in dbirth.metrics)
    # seq: 0 in NBIRTH, then one more than the message before, wrapping, through the
    # DDEATHs and DBIRTHs
    seqs = [(k, p.seq) for k, p in msgs if k != "NDEATH"]
    assert seqs[0] == ("NBIRTH", 0)
    for (_, prev), (k, seq) in pairwise(seqs):
        assert seq == (0 if k == "NBIRTH" else (prev + 1) % 256), (k, prev, seq)
    _nothing_lost("Sparkplug, a device stopped and came back", sub, db,
                  lambda m: _sample_ids(pb, m))


def test_sparkplug_profile_device_down_and_back(sparkplug_pb: Any) -> None:
    """The profile alone: DDEATH only for a device born in the session; the backlog
    of a device that is down goes as historical DDATA without a DBIRTH (it stays
    down); its next live sample brings a DBIRTH first."""
    from pymb.devices import CoolProStatus, CoolProTelemetry
    from pymb.fleet.config import MqttConfig
    from pymb.fleet.profiles import SparkplugProfile
    from pymb.store import DeviceInfo, StoredSample
    pb = sparkplug_pb
    prof = SparkplugProfile(MqttConfig("mqtt://127.0.0.1", profile="sparkplug",
                                       node=NODE, group=GROUP))
    dev = DeviceInfo("bus1", "p", "coolpro", 40, "coolpro-40")

    def rec(i: int) -> StoredSample:
        regs = __import__("array").array("H", [1500, 1500, 1500, 1500, 1500, i, 0, i])
        data = CoolProTelemetry(1.5, 1.5, 1.5, 1.5, 1.5, i, CoolProStatus(i), regs)
        return StoredSample(dev, 1700000000.0 + i, float(i), data, i)

    def kinds(msgs: Any) -> list[str]:
        return [m.topic.split("/", 2)[2] for m in msgs]

    assert prof.device_down("hub-9") == []  # never born: nothing to say
    assert kinds(prof.data(rec(1), False)) == [f"DBIRTH/{NODE}/coolpro-40",
                                               f"DDATA/{NODE}/coolpro-40"]
    assert kinds(prof.data(rec(2), False)) == [f"DDATA/{NODE}/coolpro-40"]
    down = prof.device_down("coolpro-40")
    assert kinds(down) == [f"DDEATH/{NODE}/coolpro-40"]
    assert down[0].qos == 0
    assert prof.device_down("coolpro-40") == []  # already down
    hist = prof.data(rec(3), True)
    assert kinds(hist) == [f"DDATA/{NODE}/coolpro-40"]
    assert all(m.is_historical for m in pb.FromString(hist[0].payload).metrics)
    back = prof.data(rec(4), False)
    assert kinds(back) == [f"DBIRTH/{NODE}/coolpro-40", f"DDATA/{NODE}/coolpro-40"]
    seqs = [pb.FromString(m.payload).seq for m in down + hist + back]
    assert seqs == [3, 4, 5, 6]


def test_device_health_counts_faults_in_a_row() -> None:
    """Down after DOWN_AFTER faults of any kind the logger records, with no sample
    between them; a bus that cannot reconnect counts for each of its devices;
    other events (connect, reconnect, trim, mqtt) do not count."""
    from types import SimpleNamespace as NS

    from pymb.fleet.health import DOWN_AFTER, DeviceHealth
    from pymb.store import DeviceInfo, Event
    a = DeviceInfo("b1", "p", "coolpro", 40, "coolpro-40")
    b = DeviceInfo("b1", "p", "hub", 250, "hub-250")
    h = DeviceHealth()

    def ev(kind: str, dev: DeviceInfo | None, t: float = 1.0) -> Event:
        return Event(t, 0.0, "b1", dev, kind, None, "x")

    h.sample(NS(device=a, time_utc=5.0))
    h.sample(NS(device=b, time_utc=6.0))
    for kind in ("exception", "busy", "reconnect", "connect", "trim"):
        h.event(ev(kind, a))
    assert h.take() == []
    assert DOWN_AFTER == 3
    h.event(ev("timeout", a, 7.0))
    [d] = h.take()
    assert (d.device, d.last_sample, d.time_utc) == ("coolpro-40", 5.0, 7.0)
    h.event(ev("protocol", b))
    h.sample(NS(device=b, time_utc=8.0))  # a sample: the count starts again
    h.event(ev("no_value", b))  # a hub that answered with every block unsupported
    h.event(ev("connection", None))
    assert h.take() == []
    h.event(ev("connection", None, 9.0))
    assert [(d.device, d.last_sample) for d in h.take()] == [("hub-250", 8.0)]
    assert h.down == {"coolpro-40", "hub-250"}
    h.sample(NS(device=a, time_utc=10.0))
    assert h.down == {"hub-250"}


def test_sparkplug_primary_host_state(fleet: Fleet, simulator: str, sparkplug_pb: Any,
                                      tmp_path: Path) -> None:
    """--mqtt-primary-host: no births before the host's STATE says online (the samples
    wait in the database, then go as history); a stale offline STATE (older than the
    online one) is ignored; a valid one gets an NDEATH and a new connection that waits
    again; nothing is lost."""
    pb = sparkplug_pb
    broker = fleet.broker()
    sub = fleet.subscribe(broker, f"spBv1.0/{GROUP}/+/{NODE}/#")
    host = fleet.subscribe(broker, "spBv1.0/STATE/#", client_id="scada")  # the host's client
    state_topic = "spBv1.0/STATE/scada"

    def state(online: bool, ts: int) -> None:
        body = json.dumps({"online": online, "timestamp": ts}).encode()
        host.client.publish(state_topic, body, qos=1, retain=True).wait_for_publish(10)

    def kinds(start: int = 0) -> list[str]:
        return [t.split("/")[2] for t, _ in sub.snapshot()[start:]]

    db = tmp_path / "log.sqlite"
    state(False, 1000)  # the host's death certificate, retained
    proc = fleet.log(simulator, db, *_sparkplug(broker), "--mqtt-primary-host", "scada")
    wait_until(lambda: db_count(db) >= 100, "100 samples logged", 30)
    con = sqlite3.connect(db)
    wait_until(lambda: any("connected to" in m for (m,) in con.execute(
        "SELECT message FROM events WHERE kind = 'mqtt'")), "pymb connected", 30)
    con.close()
    assert sub.snapshot() == [], "births before the primary host said online"
    waited = db_count(db)
    t1 = int(time.time() * 1000)
    state(True, t1)
    wait_until(lambda: "DDATA" in kinds(), "births and data once the host is online", 30)
    msgs = _sp(pb, sub.snapshot())
    assert msgs[0][0] == "NBIRTH"
    assert msgs[1][0] == "DBIRTH/coolpro-40"
    bd_seq = _metric(msgs[0][1], "bdSeq").long_value
    # what was logged while waiting goes as history
    wait_until(lambda: set(range(1, waited + 1)) <= _historical_ids(pb, sub.snapshot()),
               "the samples logged while waiting, as history", 60)
    # a stale offline STATE (an old session's will): ignored; a Rebirth proves the
    # connection is the same one (same bdSeq, no NDEATH between)
    state(False, t1 - 1)
    n = len(sub.snapshot())
    _rebirth(sub, pb)
    wait_until(lambda: "NBIRTH" in kinds(n), "the Rebirth's NBIRTH", 30)
    assert "NDEATH" not in kinds()
    rebirth = _sp(pb, sub.snapshot()[n:])
    nb = next(p for k, p in rebirth if k == "NBIRTH")
    assert _metric(nb, "bdSeq").long_value == bd_seq
    # the host goes offline (its will: timestamp of its online STATE): NDEATH
    state(False, t1)
    wait_until(lambda: "NDEATH" in kinds(), "the NDEATH after the host went offline", 30)
    i = kinds().index("NDEATH")
    ndeath = pb.FromString(sub.snapshot()[i][1])
    assert _metric(ndeath, "bdSeq").long_value == bd_seq
    # the new connection waits for the host again, then births with the next bdSeq
    before = db_count(db)
    wait_until(lambda: db_count(db) >= before + 50, "samples logged while offline", 30)
    assert "NBIRTH" not in kinds(i)
    state(True, int(time.time() * 1000))
    wait_until(lambda: "NBIRTH" in kinds(i), "births after the host is back", 30)
    j = i + kinds(i).index("NBIRTH")
    nb2 = pb.FromString(sub.snapshot()[j][1])
    assert _metric(nb2, "bdSeq").long_value == (bd_seq + 1) % 256
    stop_log(proc)
    _nothing_lost("Sparkplug with a primary host going offline and back", sub, db,
                  lambda m: _sample_ids(pb, m))


# -- InfluxDB line protocol ---------------------------------------------------------------

_LINE = __import__("re").compile(
    r"^(?P<m>pymb_(?:coolpro|hub|event)),(?P<tags>(?:[^ ,=\\]|\\.)+=(?:[^ ,=\\]|\\.)+"
    r"(?:,(?:[^ ,=\\]|\\.)+=(?:[^ ,=\\]|\\.)+)*) "
    r"(?P<fields>[a-z0-9_]+=(?:-?[0-9.e+-]+i?|\"(?:[^\"\\]|\\.)*\")"
    r"(?:,[a-z0-9_]+=(?:-?[0-9.e+-]+i?|\"(?:[^\"\\]|\\.)*\"))*) (?P<ts>[0-9]{19})$")


def test_influx_line_protocol_on_stdout(fleet: Fleet) -> None:
    """``--format influx --out -`` (for Telegraf's inputs.execd): every line parses as
    line protocol; a hub gives one line per channel, no-value states as strings."""
    sim = fleet.simulator("coolpro", "hub:250")
    r = run_pymb("log", "--tcp", sim.endpoint, "--device", "coolpro:40", "--device", "hub:250",
                 "--format", "influx", "--out", "-", "--seconds", "1.5", "--quiet", timeout=60)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert lines
    parsed = [_LINE.match(line) for line in lines]
    assert all(parsed), [line for line, p in zip(lines, parsed, strict=True) if not p][:3]
    kinds = {p["m"] for p in parsed if p}
    assert {"pymb_coolpro", "pymb_hub", "pymb_event"} <= kinds
    hub = [p for p in parsed if p and p["m"] == "pymb_hub"]
    first_ts = hub[0]["ts"]
    channels = [p["tags"] for p in hub if p["ts"] == first_ts]
    assert len(channels) == 100
    assert channels[0].endswith("channel=1")
    cp = next(p for p in parsed if p and p["m"] == "pymb_coolpro")
    assert "status=" in cp["fields"]
    assert cp["fields"].count("i") >= 2
    assert "device=coolpro-40" in cp["tags"]
    assert "address=40" in cp["tags"]


def test_influx_escaping() -> None:
    from pymb.store import DeviceInfo, Event
    from pymb.store.influx import event_line
    e = Event(1.5, 0.0, "line 1", DeviceInfo("line 1", "p", "hub", 2, "a,b=c"), "timeout", 7,
              'no "reply"\\')
    assert event_line(e) == ('pymb_event,kind=timeout,bus=line\\ 1,device=a\\,b\\=c '
                             'message="no \\"reply\\"\\\\",code=7i 1500000000')


def test_demo_mqtt_to_a_broker_it_is_given(fleet: Fleet, tmp_path: Path) -> None:
    """``pymb demo --mqtt URL``: every sample of the demo reaches the broker, the
    demo's count of what its subscriber received is true, and it says how to
    watch them."""
    import re
    broker = fleet.broker()
    sub = fleet.subscribe(broker, "pymb/demo/#")
    db = tmp_path / "demo.sqlite"
    r = run_pymb("demo", "--seconds", "2", "--mqtt", broker.url, "--out", str(db))
    assert r.returncode == 0, r.stderr
    assert f"mosquitto_sub -h 127.0.0.1 -p {broker.port} -t 'pymb/demo/#' -v" in r.stderr
    want = db_ids(db)
    m = re.search(r"mqtt: +([\d,]+) of ([\d,]+) samples received", r.stdout)
    assert m, r.stdout
    assert int(m[1].replace(",", "")) == int(m[2].replace(",", "")) == len(want), r.stdout
    assert "did not reach it" not in r.stdout, r.stdout
    # the faults by kind add up to the faults: the broker's events are not faults
    faults = re.search(r"faults seen: (\d+)(?: \((.*)\))?$", r.stdout, re.M)
    assert faults, r.stdout
    kinds = faults[2].split(", ") if faults[2] else []
    assert sum(int(k.split()[0]) for k in kinds) == int(faults[1]), r.stdout
    assert not any(k.endswith(" mqtt") for k in kinds), r.stdout
    sub.wait_until(lambda msgs: set(plain_ids(msgs)) >= want, 30,
                   "the demo's samples at the test's subscriber")
    assert set(plain_ids(sub.snapshot())) == want


def test_demo_counts_what_the_broker_acknowledged_but_had_not_yet_delivered(
        fleet: Fleet) -> None:
    """A QoS 1 acknowledgement to the publisher says the broker took the message,
    not that another subscriber has it: the demo's subscriber waits for the
    acknowledged samples (bounded) instead of counting at once. Its thread is held
    on the lock of its message handler while the publisher gets every PUBACK."""
    from pymb.commands.demo_mqtt import Watch
    from pymb.fleet.config import MqttConfig
    broker = fleet.broker()
    watch = Watch(MqttConfig(broker.url, node="demo"), "pymb/demo/#")
    assert watch.start(15)
    pub = paho.Client(paho.CallbackAPIVersion.VERSION2, client_id="pymb-test-pub")
    pub.connect("127.0.0.1", broker.port)
    pub.loop_start()
    want = set(range(1, 61))
    try:
        with watch.cond:  # the watch's network thread cannot hand a message over
            infos = [pub.publish("pymb/demo/junk", b"not JSON", qos=1),
                     pub.publish("pymb/demo/status", b"online", qos=1)]
            infos += [pub.publish(f"pymb/demo/dev-{i % 3}", json.dumps({"sample": i}), qos=1)
                      for i in sorted(want)]
            for info in infos:
                info.wait_for_publish(30)
                assert info.is_published()
            assert watch.ids == set()  # every PUBACK in, nothing delivered yet
        assert watch.wait_for(want, 30) == want  # what is not a sample is ignored
        assert watch.wait_for({61}, 0) == set()  # never sent: no wait, not counted
    finally:
        pub.disconnect()
        pub.loop_stop()
        watch.close()


def test_demo_mqtt_starts_its_own_mosquitto() -> None:
    r = run_pymb("demo", "--seconds", "1", "--mqtt", "--quiet")
    assert r.returncode == 0, r.stderr
    assert "samples received by a subscriber" in r.stdout


def test_catch_up_is_paced_and_live_data_keeps_flowing(fleet: Fleet, simulator: str,
                                                       tmp_path: Path) -> None:
    """A backlog (here: 8 s of samples logged without a broker, 1,600 asked for,
    at least 300 on a loaded machine) goes at catchup_rate, while the
    samples taken now go at once, ahead of it."""
    db = tmp_path / "log.sqlite"
    r = run_pymb("log", "--tcp", simulator, "--device", "coolpro:40", "--interval", "0.005",
                 "--out", str(db), "--quiet", "--seconds", "8")
    assert r.returncode == 0, r.stderr
    backlog = db_count(db)
    assert backlog >= 300  # 3 s at catchup_rate: the pacing shows (a loaded machine logs fewer)
    broker = fleet.broker()
    sub = fleet.subscribe(broker, "pymb/#")
    cfg = tmp_path / "pymb.toml"
    cfg.write_text(f"""
[output]
path = "{db}"
[mqtt]
url = "{broker.url}"
node = "{NODE}"
catchup_rate = 100
[[bus]]
tcp = "{simulator}"
interval = 0.01
[[bus.device]]
type = "coolpro"
address = 40
""")
    proc = fleet.pymb("log", "--config", str(cfg))
    t0 = time.monotonic()
    # live samples arrive while most of the backlog has not
    wait_until(lambda: sum(i > backlog for i in plain_ids(sub.snapshot())) >= 20,
               "20 live samples", 30)
    old = sum(i <= backlog for i in set(plain_ids(sub.snapshot())))
    assert old < backlog / 2, f"{old} of {backlog} old samples already: not paced"
    wait_until(lambda: set(range(1, backlog + 1)) <= set(plain_ids(sub.snapshot())),
               "the whole backlog", 60)
    took = time.monotonic() - t0
    stop_log(proc)
    # 100 messages/s: the backlog cannot have gone much faster (bursts of 10 allowed)
    assert took >= (backlog - 10) / 100 * 0.9, took
    _nothing_lost("a paced catch-up", sub, db)


def test_readme_mqtt_toml_example() -> None:
    from pymb.fleet.config import from_table
    block = claim_one("docs/fleet.md", "toml", how="load", contains="[mqtt]\n").text
    import tomllib
    cfg = from_table(tomllib.loads(block)["mqtt"], "docs/fleet.md")
    assert (cfg.tls, cfg.port, cfg.profile, cfg.node) == (True, 8883, "sparkplug", "gateway-7")



def test_hub_samples_in_both_profiles(fleet: Fleet, sparkplug_pb: Any,
                                      tmp_path: Path) -> None:
    """A sensor hub: plain JSON lists per quantity with null and the states; Sparkplug
    701 metrics declared (sample + 100 channels x 7), no-value ones is_null."""
    broker = fleet.broker()
    sub = fleet.subscribe(broker, "#")
    sim = fleet.simulator("hub:250")
    for profile, topic in (("plain", f"pymb/{NODE}/hub-250"),
                           ("sparkplug", f"spBv1.0/{GROUP}/DDATA/{NODE}/hub-250")):
        # A hub's message (701 metrics) is costly to build: poll at a pace the
        # forwarder keeps up with on a loaded machine, and stop once messages
        # have arrived, so the drain on stopping has a sample or two to send.
        db = tmp_path / f"{profile}.sqlite"
        proc = fleet.log(sim.endpoint, db, "--mqtt", broker.url, "--mqtt-profile", profile,
                         "--mqtt-node", NODE, "--mqtt-group", GROUP, "--interval", "0.5",
                         device="hub:250")

        def arrived(t: str = topic) -> bool:
            return sum(m[0] == t for m in sub.snapshot()) >= 3

        wait_until(arrived, f"3 {profile} hub messages", 60)
        err = stop_log(proc)
        assert "nothing left to send" in err, err
    msgs = sub.snapshot()
    plain = [json.loads(p) for t, p in msgs if t == f"pymb/{NODE}/hub-250"]
    assert plain
    h = plain[0]
    assert h["type"] == "hub"
    assert len(h["values"]["temperature_c"]) == 100
    assert list(h) == [*PLAIN_KEYS, "states", "unsupported"]
    assert h["unsupported"] == []
    con = sqlite3.connect(tmp_path / "plain.sqlite")
    rows = con.execute("SELECT channel, temperature_c, temperature_c_state FROM hub "
                       "WHERE sample_id = ? ORDER BY channel", (h["sample"],)).fetchall()
    states = dict(con.execute("SELECT code, name FROM states").fetchall())
    con.close()
    assert h["values"]["temperature_c"] == [r[1] for r in rows]
    assert h["states"]["temperature_c"] == [states[r[2]] for r in rows]
    assert None in h["values"]["humidity_pct"] or None in h["values"]["temperature_c"]
    sp = [(t, sparkplug_pb.FromString(p)) for t, p in msgs if t.startswith("spBv1.0/")]
    dbirth = next(p for t, p in sp if t == f"spBv1.0/{GROUP}/DBIRTH/{NODE}/hub-250")
    assert len(dbirth.metrics) == 701
    names = {m.alias: m.name for m in dbirth.metrics}
    ddata = next(p for t, p in sp if t == f"spBv1.0/{GROUP}/DDATA/{NODE}/hub-250")
    nulls = [m for m in ddata.metrics if m.is_null]
    assert nulls
    assert all(m.properties.keys[0] == "Quality" for m in nulls)
    assert all(names[m.alias].startswith("channel ") for m in nulls)


def test_sample_ids_never_repeat_after_an_age_trim_of_everything(tmp_path: Path) -> None:
    """The forwarder's cursor and its consumers rely on ids that only increase."""
    from pymb.devices import decode_hub
    from pymb.store import DeviceInfo, Sample, SqliteSink

    regs = __import__("array").array("H", [0] * 700)
    dev = DeviceInfo("b", "p", "hub", 1, "hub-1")
    sink = SqliteSink(tmp_path / "t.sqlite", max_age=100.0)
    for i in range(5):
        sink.write(Sample(dev, time.time() - 1000 + i, float(i), decode_hub(regs)))
    sink.commit()
    sink.trim()
    sink.write(Sample(dev, time.time(), 0.0, decode_hub(regs)))
    sink.commit()
    ids = [i for (i,) in sink.db.execute("SELECT id FROM samples ORDER BY id")]
    assert ids == [5, 6]
    sink.close()


@pytest.mark.parametrize("value", [-(1 << 70), -(1 << 64) - 1, 1 << 64, (1 << 70) + 5])
def test_a_uint64_out_of_64_bits_is_encoded_in_its_low_64_bits(value: int) -> None:
    """protobuf's varint carries 64 bits: a value outside them is sent as its
    low 64 bits (as protobuf's own encoders truncate), never an endless loop."""
    from pymb.fleet.protobuf import DataType, Metric, decode, encode_payload

    data = encode_payload([Metric("x", None, DataType.UINT64, value)])
    metric = decode(data)[2][0]
    assert isinstance(metric, bytes)
    assert decode(metric)[11] == [value & (1 << 64) - 1]  # long_value
    # the bytes as the protobuf encoding spells them: key 11/varint, then 7 bits a byte
    low, want = value & (1 << 64) - 1, bytearray()
    while low > 0x7F:
        want.append(low & 0x7F | 0x80)
        low >>= 7
    assert metric.endswith(b"\x58" + bytes(want) + bytes([low]))
