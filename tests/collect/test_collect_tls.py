"""``pymb collect`` with ``pymb log``'s broker options: TLS verifying the broker
(``--mqtt-ca``), a client certificate and a password file, against a
mosquitto that requires all three; a board publishing the same way; a wrong
password or a CA that did not sign the broker: exit 4 at the start."""

from __future__ import annotations

from pathlib import Path

import pytest

pytest.register_assert_rewrite("mqtt_broker", "collectkit")
from collectkit import (  # noqa: E402
    Collectors,
    expected_plain,
    same_facts,
    sqlite_count,
    sqlite_facts,
    stop,
    wait_rows,
    wait_subscribed,
)
from conftest import run_pymb  # noqa: E402
from mqtt_broker import Fleet, db_ids  # noqa: E402

from pymb.fleet.broker import Certificates, make_certificates  # noqa: E402

pytest_plugins = ["mqtt_broker", "collectkit"]


def test_tls_client_certificate_and_password(fleet: Fleet, collectors: Collectors,
                                             certificates: Certificates,
                                             tmp_path: Path) -> None:
    certs = certificates
    broker = fleet.broker(tls=certs, require_client_cert=True,
                          users={"collector": "c0ll pass", "gw": "g", "test": "t"})
    sub = fleet.subscribe(broker, "pymb/+/+", tls=certs, user=("test", "t"))
    tls = ["--mqtt-ca", certs.ca, "--mqtt-cert", certs.client_cert,
           "--mqtt-key", certs.client_key]
    pw = tmp_path / "pw"
    pw.write_text("c0ll pass\n")
    out = tmp_path / "fleet.sqlite"
    col = collectors.start(broker.url, str(out), *tls, "--mqtt-user", "collector",
                           "--mqtt-password-file", str(pw), "--client-id", "tls1")
    wait_subscribed(col)
    sim = fleet.simulator("coolpro")
    log_db = tmp_path / "board.sqlite"
    log = fleet.log(sim.endpoint, log_db, "--mqtt", broker.url, *tls, "--mqtt-user", "gw",
                    "--mqtt-node", "gw1", seconds=2, env={"PYMB_MQTT_PASSWORD": "g"})
    _, err = log.communicate(timeout=60)
    assert log.returncode == 0, err
    ids = db_ids(log_db)
    from mqtt_broker import plain_ids
    sub.wait_until(lambda m: ids <= set(plain_ids(m)), 60, "every sample at the subscriber")
    expected = expected_plain(sub.snapshot())
    wait_rows(lambda: sqlite_count(out), len(expected), "every value stored over TLS")
    stop(col)
    same_facts(sqlite_facts(out), expected)
    # refused: a wrong password, a CA that did not sign the broker's certificate
    pw.write_text("wrong\n")
    r = run_pymb("collect", "--mqtt", broker.url, "--out", str(out), *tls, "--mqtt-user",
                 "collector", "--mqtt-password-file", str(pw), "--client-id", "tls2")
    assert r.returncode == 4, r.stderr
    assert "refused" in r.stderr, r.stderr
    other = make_certificates(tmp_path / "other")
    r = run_pymb("collect", "--mqtt", broker.url, "--out", str(out), "--mqtt-ca", other.ca,
                 "--client-id", "tls3")
    assert r.returncode == 4, r.stderr
    assert "cannot reach the broker" in r.stderr, r.stderr
    assert "certificate was refused: self-signed certificate in certificate chain (not " \
        "signed by the CA given)" in r.stderr, r.stderr
    assert "Traceback" not in r.stderr
