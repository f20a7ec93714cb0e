"""``--mqtt-user NAME`` with no password (no ``--mqtt-password-file``, no
``$PYMB_MQTT_PASSWORD``: an environment variable left unset) and a broker that
wants one: the refusal says that no password was given, in ``pymb log`` and
``pymb collect`` alike; with a wrong password it does not."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import pytest

pytest.register_assert_rewrite("mqtt_broker")
from conftest import PYMB_ENV, run_pymb, wait_until  # noqa: E402
from mqtt_broker import Fleet, stop_log  # noqa: E402

pytest_plugins = ["mqtt_broker"]  # the fixtures: fleet, mosquitto, simulator

HINT = "no password was given: --mqtt-password-file FILE or $PYMB_MQTT_PASSWORD"
UNSET = {k: v for k, v in PYMB_ENV.items() if k != "PYMB_MQTT_PASSWORD"}


def _refused(db: Path) -> bool:
    """Whether the broker's refusal is in the event log of ``db`` yet."""
    try:
        con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    except sqlite3.Error:
        return False
    try:
        return bool(con.execute("SELECT COUNT(*) FROM events WHERE kind = 'mqtt' "
                                "AND message LIKE '%refused%'").fetchone()[0])
    except sqlite3.Error:
        return False  # not made yet
    finally:
        con.close()


@pytest.mark.parametrize("password", [None, "wrong"])
def test_log_says_the_password_is_missing(fleet: Fleet, simulator: str, tmp_path: Path,
                                          password: str | None) -> None:
    broker = fleet.broker(users={"gw": "s3cret"})
    db = tmp_path / "log.sqlite"
    env = {**UNSET} if password is None else {**UNSET, "PYMB_MQTT_PASSWORD": password}
    proc = fleet.log(simulator, db, "--mqtt", broker.url, "--mqtt-user", "gw", env=env)
    wait_until(lambda: _refused(db), "the refusal in the event log", 60)
    err = stop_log(proc)
    said = [line for line in err.splitlines() if "refused" in line]
    assert said, err
    assert (HINT in said[0]) == (password is None), said


@pytest.mark.parametrize("password", [None, "wrong"])
def test_collect_says_the_password_is_missing(fleet: Fleet, tmp_path: Path,
                                              password: str | None) -> None:
    broker = fleet.broker(users={"gw": "s3cret"})
    env = {**UNSET} if password is None else {**UNSET, "PYMB_MQTT_PASSWORD": password}
    r = run_pymb("collect", "--mqtt", broker.url, "--mqtt-user", "gw", "--out",
                 str(tmp_path / "fleet.sqlite"), env=env, timeout=60)
    assert r.returncode == 4, r.stderr
    assert len(r.stderr.splitlines()) == 1, r.stderr
    assert "the broker refused the connection" in r.stderr
    assert (HINT in r.stderr) == (password is None), r.stderr
