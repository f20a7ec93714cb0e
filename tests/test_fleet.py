"""Fleet: every logged sample reaches a real mosquitto, through outages.

The broker is Debian's mosquitto on a free loopback port (tests/mqtt_broker.py);
pymb log runs as a child process against a simulated CoolPro on Modbus TCP; a
paho subscriber with a persistent session records what arrives. At the end the
set of sample ids received must equal the set in the database; duplicates are
counted and reported (at least once, never lost).
"""

from __future__ import annotations

import json
import signal
import sqlite3
import time
from pathlib import Path
from typing import Any

import pytest
from mqtt_broker import (
    Subscriber,
    db_count,
    db_ids,
    duplicates,
    plain_ids,
    start_log,
    stop_log,
    wait_for,
)

from pymb.fleet.broker import Certificates, Mosquitto

pytest_plugins = ["mqtt_broker"]  # the fixtures: mosquitto, simulator, certificates, ...
NODE = "gw-test"


def _all_arrived(sub: Subscriber, db: Path, ids: Any = plain_ids) -> tuple[set[int], int]:
    want = db_ids(db)
    wait_for(lambda: set(ids(sub.snapshot())) >= want, 30,
             f"all {len(want)} samples of the database at the subscriber")
    got = ids(sub.snapshot())
    return want, duplicates(got)


def _report(what: str, want: set[int], got: list[int]) -> None:
    print(f"\n{what}: {len(want)} samples in the database, {len(set(got))} distinct "
          f"received, {duplicates(got)} duplicates")


def test_broker_restart_mid_run_loses_nothing(mosquitto, simulator, tmp_path: Path) -> None:
    broker: Mosquitto = mosquitto()
    sub = Subscriber(broker, f"pymb/{NODE}/#")
    db = tmp_path / "log.sqlite"
    proc = start_log(simulator, db, "--mqtt", broker.url, "--mqtt-node", NODE)
    try:
        wait_for(lambda: len(plain_ids(sub.snapshot())) >= 50, 30, "50 samples live")
        broker.stop()
        before = db_count(db)
        wait_for(lambda: db_count(db) >= before + 100, 30, "100 samples logged while down")
        broker.start()
        wait_for(lambda: max(plain_ids(sub.snapshot())) > before + 100, 30,
                 "live samples after the restart")
        err = stop_log(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
    want, _ = _all_arrived(sub, db)
    got = plain_ids(sub.snapshot())
    _report("broker restart", want, got)
    assert set(got) == want
    assert "nothing left to send" in err
    # the retained status: online while connected, offline after the clean end
    status = [p for t, p in sub.snapshot() if t.endswith("/status")]
    assert status[0] == b"online" and status[-1] == b"offline"
    con = sqlite3.connect(db)
    assert con.execute("SELECT sample_id FROM outbox").fetchone()[0] == max(want)
    con.close()
    sub.close()


def test_broker_stalled_3s_loses_nothing(mosquitto, simulator, tmp_path: Path) -> None:
    broker: Mosquitto = mosquitto()
    sub = Subscriber(broker, f"pymb/{NODE}/#")
    db = tmp_path / "log.sqlite"
    proc = start_log(simulator, db, "--mqtt", broker.url, "--mqtt-node", NODE)
    try:
        wait_for(lambda: len(plain_ids(sub.snapshot())) >= 50, 30, "50 samples live")
        broker.pause()
        t0 = time.monotonic()
        before = db_count(db)
        try:
            wait_for(lambda: time.monotonic() - t0 >= 3.0 and db_count(db) > before + 50, 30,
                     "3 s of stall with samples logged")
        finally:
            broker.resume()
        wait_for(lambda: max(plain_ids(sub.snapshot())) > before + 50, 30,
                 "samples after the stall")
        stop_log(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
    want, _ = _all_arrived(sub, db)
    got = plain_ids(sub.snapshot())
    _report("broker stalled 3 s", want, got)
    assert set(got) == want
    sub.close()


def test_pymb_sigkilled_and_restarted_loses_nothing(mosquitto, simulator,
                                                     tmp_path: Path) -> None:
    broker: Mosquitto = mosquitto()
    sub = Subscriber(broker, f"pymb/{NODE}/#")
    db = tmp_path / "log.sqlite"
    proc = start_log(simulator, db, "--mqtt", broker.url, "--mqtt-node", NODE)
    try:
        wait_for(lambda: len(plain_ids(sub.snapshot())) >= 200, 30, "200 samples live")
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
        killed_at = db_count(db)
        # the will: the broker says offline for the killed pymb
        wait_for(lambda: sub.snapshot()[-1] == (f"pymb/{NODE}/status", b"offline"), 30,
                 "the last will (offline)")
        proc = start_log(simulator, db, "--mqtt", broker.url, "--mqtt-node", NODE)
        wait_for(lambda: max(plain_ids(sub.snapshot())) > killed_at + 50, 30,
                 "samples of the second run")
        stop_log(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
    want, _ = _all_arrived(sub, db)
    got = plain_ids(sub.snapshot())
    _report("pymb SIGKILLed and restarted", want, got)
    assert set(got) == want
    sub.close()


def test_plain_payload(mosquitto, simulator, tmp_path: Path) -> None:
    broker: Mosquitto = mosquitto()
    sub = Subscriber(broker, "plant/#")
    db = tmp_path / "log.sqlite"
    proc = start_log(simulator, db, "--mqtt", broker.url, "--mqtt-node", "n1",
                     "--mqtt-prefix", "plant", seconds=1.5)
    proc.communicate(timeout=60)
    assert proc.returncode == 0
    _all_arrived(sub, db)
    data = [(t, json.loads(p)) for t, p in sub.snapshot() if not t.endswith("/status")]
    t, first = data[0]
    assert t == "plant/n1/coolpro-40"
    assert {"device", "type", "address", "sample", "time_utc", "time", "values"} <= set(first)
    assert first["device"] == "coolpro-40" and first["type"] == "coolpro"
    assert first["address"] == 40 and first["time"].endswith("Z")
    con = sqlite3.connect(db)
    row = con.execute("SELECT s.time_utc, c.output_voltage_v FROM samples s JOIN coolpro c "
                      "ON c.sample_id = s.id WHERE s.id = ?", (first["sample"],)).fetchone()
    con.close()
    assert first["time_utc"] == row[0]
    assert first["values"]["output_voltage_v"] == row[1]
    sub.close()


def test_tls_with_client_certificate_and_password(mosquitto, simulator, certificates,
                                                   tmp_path: Path) -> None:
    certs: Certificates = certificates
    broker: Mosquitto = mosquitto(tls=certs, require_client_cert=True,
                                  users={"gw": "s3cret pass", "test": "t"})
    sub = Subscriber(broker, "pymb/#", tls=certs, user=("test", "t"))
    pw = tmp_path / "pw"
    pw.write_text("s3cret pass\n")
    db = tmp_path / "log.sqlite"
    tls = ["--mqtt-ca", certs.ca, "--mqtt-cert", certs.client_cert,
           "--mqtt-key", certs.client_key]
    proc = start_log(simulator, db, "--mqtt", broker.url, "--mqtt-node", NODE, *tls,
                     "--mqtt-user", "gw", "--mqtt-password-file", str(pw), seconds=1.5)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    want, _ = _all_arrived(sub, db)
    assert want
    # the password from the environment instead of a file
    db2 = tmp_path / "env.sqlite"
    proc = start_log(simulator, db2, "--mqtt", broker.url, "--mqtt-node", "n2", *tls,
                     "--mqtt-user", "gw", env={"PYMB_MQTT_PASSWORD": "s3cret pass"},
                     seconds=1.0)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    assert "nothing left to send" in err
    # a wrong password: refused, nothing lost (kept for the next run)
    db3 = tmp_path / "bad.sqlite"
    proc = start_log(simulator, db3, "--mqtt", broker.url, "--mqtt-node", "n3", *tls,
                     "--mqtt-user", "gw", env={"PYMB_MQTT_PASSWORD": "wrong"}, seconds=1.0)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    assert "not yet acknowledged" in err and "0 samples acknowledged" in err
    sub.close()


def test_tls_verifies_the_broker(mosquitto, simulator, certificates, tmp_path: Path) -> None:
    """A CA that did not sign the broker's certificate: no connection, nothing sent."""
    from pymb.fleet.broker import make_certificates
    other = make_certificates(tmp_path / "other")
    broker: Mosquitto = mosquitto(tls=certificates)
    db = tmp_path / "log.sqlite"
    proc = start_log(simulator, db, "--mqtt", broker.url, "--mqtt-ca", other.ca,
                     seconds=1.0)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    assert "0 samples acknowledged" in err


@pytest.mark.parametrize("argv, message", [
    (["--mqtt", "http://x"], "bad MQTT URL"),
    (["--mqtt", "mqtt://u:p@host"], "no user or password in the MQTT URL"),
    (["--mqtt", "mqtt://host", "--mqtt-ca", "/etc/hostname"], "need an mqtts:// URL"),
    (["--mqtt", "mqtts://host", "--mqtt-cert", "/etc/hostname"], "needs both"),
    (["--mqtt", "mqtts://host", "--mqtt-ca", "/nonexistent"], "cannot be read"),
    (["--mqtt", "mqtt://host", "--mqtt-node", "a/b"], "without '/'"),
    (["--mqtt-node", "x"], "need --mqtt URL"),
    (["--mqtt", "mqtt://host", "--format", "csv", "--out", "-"], "use --format sqlite"),
])
def test_bad_mqtt_options_are_one_line_errors(argv: list[str], message: str,
                                              tmp_path: Path) -> None:
    import subprocess
    import sys
    r = subprocess.run([sys.executable, "-m", "pymb", "log", "--tcp", "127.0.0.1:1",
                        "--device", "coolpro", *argv], capture_output=True, text=True,
                       cwd=tmp_path, timeout=60)
    assert r.returncode == 2, r.stderr
    assert message in r.stderr and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def test_toml_mqtt_table(mosquitto, simulator, tmp_path: Path) -> None:
    broker: Mosquitto = mosquitto()
    sub = Subscriber(broker, "site/#")
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
    import subprocess
    import sys
    r = subprocess.run([sys.executable, "-m", "pymb", "log", "--config", str(cfg),
                        "--seconds", "1"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    _all_arrived(sub, db)
    assert all(t.startswith("site/toml-node/") for t, _ in sub.snapshot())
    cfg.write_text(cfg.read_text().replace('prefix = "site"', 'prefix = 3'))
    r = subprocess.run([sys.executable, "-m", "pymb", "log", "--config", str(cfg),
                        "--seconds", "1"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "prefix has the wrong type" in r.stderr
    sub.close()


def test_trim_records_unsent_samples(tmp_path: Path) -> None:
    """The size/age limits never delete samples not yet forwarded silently."""
    from pymb.devices import decode_hub
    from pymb.fleet.source import Source
    from pymb.store import DeviceInfo, Sample, SqliteSink

    regs = __import__("array").array("H", [0] * 700)
    dev = DeviceInfo("b", "p", "hub", 1, "hub-1")
    db = tmp_path / "t.sqlite"
    sink = SqliteSink(db, max_age=100.0)
    now = time.time()
    for i in range(30):
        sink.write(Sample(dev, now - 300 + i, float(i), decode_hub(regs)))
    sink.commit()
    src = Source(str(db))
    src.set_cursor("dest", 10)  # 10 sent; 20 old ones not yet
    for i in range(5):
        sink.write(Sample(dev, now - 5 + i, float(i), decode_hub(regs)))
    sink.commit()
    assert sink.trim() == 30
    events = sink.db.execute("SELECT kind, code, message FROM events").fetchall()
    assert events == [("trim", 20, "the size/age limit deleted 20 samples not yet forwarded "
                                    "to the MQTT broker (ids 11..30)")]
    src.close()
    sink.close()
