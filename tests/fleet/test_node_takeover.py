"""Two loggers with one node name take the broker's session from each other
(the same client id): each says so once, as an event and a line on stderr,
and reconnects with a growing backoff instead of hundreds of times a minute;
a broker restarted a few times is no takeover. ``pymb log`` processes,
Debian's mosquitto, a simulated CoolPro."""

from __future__ import annotations

import sqlite3
import subprocess
import time
from collections.abc import Callable
from pathlib import Path

import pytest

pytest.register_assert_rewrite("mqtt_broker")
from conftest import wait_until  # noqa: E402
from mqtt_broker import Fleet, stop_log  # noqa: E402

from pymb.fleet.takeover import IN_A_ROW, STABLE_S, Takeovers  # noqa: E402

pytest_plugins = ["mqtt_broker"]

SAID = "is another client connected as pymb-{profile}-twin (a second logger with the node name"


def _events(db: Path, like: str) -> list[float]:
    """The times of the events whose message holds ``like``."""
    if not db.exists():
        return []
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    try:
        return [t for (t,) in con.execute("SELECT time_utc FROM events WHERE message LIKE ?",
                                          (f"%{like}%",))]
    except sqlite3.Error:  # not made yet
        return []
    finally:
        con.close()


@pytest.mark.parametrize("profile", ["plain", "sparkplug"])
def test_two_loggers_with_one_node_name_say_so_once_without_a_storm(
        fleet: Fleet, tmp_path: Path, profile: str) -> None:
    broker = fleet.broker()
    sim = fleet.simulator("coolpro:40")
    mqtt = ["--mqtt", broker.url, "--mqtt-node", "twin", "--mqtt-profile", profile]
    dbs = [tmp_path / "a.sqlite", tmp_path / "b.sqlite"]
    procs: list[subprocess.Popen[str]] = []
    for db in dbs:
        procs.append(fleet.log(sim.endpoint, db, *mqtt, commit=0.5))
        time.sleep(1)  # (the second takes the first one's session)
    said = SAID.format(profile=profile)
    wait_until(lambda: all(_events(db, said) for db in dbs), "both loggers to say it", 90)
    since = time.time()
    time.sleep(15)
    for db in dbs:
        # from the detection on the backoff doubles (2, 4, 8 s...): a few connections,
        # where the first 0.5 s retry took a dozen in 15 s
        assert len(_events(db, "connected to mqtt://")) - len(
            [t for t in _events(db, "connected to mqtt://") if t < since]) <= 4
        assert len(_events(db, said)) == 1
    for proc in procs:
        err = stop_log(proc)
        assert err.count(said) == 1, err
        assert "Traceback" not in err


def test_a_broker_restarted_three_times_is_not_a_takeover(fleet: Fleet, tmp_path: Path,
                                                          ) -> None:
    """A broker restarted a few times within a minute is not another logger
    taking the session: the logger reconnects each time as after any outage
    and says nothing of a second logger with its node name."""
    broker = fleet.broker()
    sim = fleet.simulator("coolpro:40")
    db = tmp_path / "r.sqlite"
    proc = fleet.log(sim.endpoint, db, "--mqtt", broker.url, "--mqtt-node", "n1", commit=0.5)
    connected = "connected to mqtt://"
    wait_until(lambda: len(_events(db, connected)) == 1, "the first connection", 60)

    def count(like: str, n: int) -> Callable[[], bool]:
        return lambda: len(_events(db, like)) >= n

    for n in range(IN_A_ROW):  # each connection lives a few seconds (< 60 s)
        broker.stop()
        # away long enough for the logger's first retry (0.5 s after the end) to fail
        wait_until(count("cannot connect to", n + 1),
                   "a retry refused while the broker is down", 60)
        time.sleep(0.5)
        broker.start()
        wait_until(count(connected, n + 2), "the reconnection", 60)
    assert not _events(db, "is another client connected as")
    err = stop_log(proc)
    assert "is another client connected as" not in err, err
    assert "Traceback" not in err


def test_what_counts_as_a_takeover() -> None:
    """Short-lived connections ended by the broker, in a row; one that lasts,
    or one this side ended, starts the count over."""
    now = [0.0]
    t = Takeovers("pymb-plain-n1", "n1", 30.0, clock=lambda: now[0])

    def ended(after: float, by_broker: bool = True, taken_over: bool = False,
              ) -> tuple[bool, str | None]:
        t.up()
        now[0] += after
        return t.down(by_broker, taken_over)

    assert ended(1.0) == (True, None)  # one glitch: the backoff starts over
    for _ in range(IN_A_ROW - 2):
        assert ended(1.0) == (False, None)  # in a row: it grows
    anew, line = ended(1.0)
    assert not anew
    assert line is not None
    assert line.startswith(f"the broker ended {IN_A_ROW} connections in a row within 60 s")
    assert line.endswith("reconnecting with a backoff up to 30 s")
    assert ended(1.0) == (False, None)  # said once
    assert ended(STABLE_S) == (True, None)  # a connection that lasted: over
    assert not t.said
    assert ended(1.0, by_broker=False) == (True, None)  # this side ended it
    anew, line = ended(1.0, taken_over=True)  # the broker said so: at once
    assert anew
    assert line is not None
    assert line.startswith("the broker says another client took over this session: is "
                           "another client connected as pymb-plain-n1 (a second logger "
                           "with the node name 'n1')?")
    assert ended(STABLE_S) == (True, None)
    assert ended(1.0) == (True, None)
    t.away()  # a connection attempt failed: the broker was away, not taken over
    assert ended(1.0) == (True, None)  # (without it: False, a second in a row)
