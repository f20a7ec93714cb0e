"""A broker's certificate refused over ``mqtts://`` is said in words, naming the
CAs it was checked against: the system's (with the option that gives another)
when no ``--mqtt-ca`` was given, else the CA given. ``pymb log`` against
Debian's mosquitto speaking TLS with a CA made here."""

from __future__ import annotations

from pathlib import Path

import pytest

pytest.register_assert_rewrite("mqtt_broker")
from conftest import run_pymb  # noqa: E402
from mqtt_broker import Fleet  # noqa: E402

from pymb.fleet.broker import Certificates, make_certificates  # noqa: E402

pytest_plugins = ["mqtt_broker"]  # the fixtures: fleet, mosquitto, simulator, certificates

REFUSED = "the broker's certificate was refused: self-signed certificate in certificate chain"


@pytest.mark.parametrize(("ca", "why"), [
    (None, "(not signed by any of the system's trusted CAs: give the broker's CA with "
           "--mqtt-ca FILE)"),
    ("other", "(not signed by the CA given)"),
])
def test_a_refused_broker_certificate_names_the_cas(
        fleet: Fleet, simulator: str, certificates: Certificates, tmp_path: Path,
        ca: str | None, why: str) -> None:
    broker = fleet.broker(tls=certificates)
    flags = [] if ca is None else ["--mqtt-ca", make_certificates(tmp_path / ca).ca]
    r = run_pymb("log", "coolpro", "--tcp", simulator, "--out", str(tmp_path / "x.sqlite"),
                 "--mqtt", broker.url, "--seconds", "2", "--quiet", *flags, timeout=60)
    assert r.returncode == 0, r.stderr
    assert f"{REFUSED} {why}" in r.stderr, r.stderr
    assert "_ssl.c" not in r.stderr
