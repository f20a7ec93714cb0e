"""A month in an hour: ``pymb log`` of a sensor hub and a CoolPro forwarding
to mosquitto for PYMB_MONTH_SECONDS (default 1800), while everything a board
lives through happens to it, again and again: the broker restarts and
stalls, the logger is SIGKILLed, the disk (a small tmpfs) fills and is
freed, the wall clock steps forward and back (libfaketime). A supervisor
restarts the logger as ``Restart=on-failure`` would. At the end the
subscriber holds every id the database holds, and no other (duplicates
counted, never lost), the database is intact, and the last logger's memory
and descriptors stayed flat.

    PYMB_MONTH_SECONDS=180 .venv/bin/python -m pytest -m slow tests/service/test_month_soak.py -s
"""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import time
from collections.abc import Callable
from pathlib import Path

import pytest

pytest.register_assert_rewrite("mqtt_broker", "disks")
from conftest import PYMB, open_fds, rss_kb, wait_until  # noqa: E402
from disks import Tmpfs, need_root  # noqa: E402
from mqtt_broker import Fleet, db_ids, duplicates, plain_ids  # noqa: E402
from servicekit import faketime_env, set_clock  # noqa: E402

pytest_plugins = ["mqtt_broker"]  # the fixtures: fleet, ...
NODE = "gw-month"


class Supervised:
    """``pymb log`` kept running as systemd would (Restart=on-failure, RestartSec=1)."""

    def __init__(self, argv: list[str], env: dict[str, str]) -> None:
        self.argv, self.env = argv, env
        self.proc: subprocess.Popen[bytes] | None = None
        self.exits: list[int] = []  #: exit statuses, in order (-9: our SIGKILL)
        self.started = 0
        self.start()

    def start(self) -> None:
        """A new logger."""
        self.proc = subprocess.Popen(self.argv, env=self.env, stdout=subprocess.DEVNULL,
                                     stderr=subprocess.DEVNULL, start_new_session=True)
        self.started += 1
        self.since = time.monotonic()

    def watch(self) -> bool:
        """Restart a logger that ended (after a second); True if one did."""
        assert self.proc is not None
        code = self.proc.poll()
        if code is None:
            return False
        self.exits.append(code)
        assert code in (-9, 5), f"the logger exited {code}"  # our kill, the full disk
        time.sleep(1.0)  # RestartSec
        self.start()
        return True

    def kill(self) -> None:
        """SIGKILL (a crash, the watchdog): restarted by watch()."""
        assert self.proc is not None
        self.proc.kill()
        self.proc.wait()

    def stop(self) -> int:
        """SIGTERM: the clean end (the forwarder drains)."""
        assert self.proc is not None
        self.proc.send_signal(signal.SIGTERM)
        return self.proc.wait(180)


def _stopped_full(logger: Supervised, n: int) -> Callable[[], bool]:
    """True once a logger exited 5 (the full disk) since exit number ``n``."""
    def stopped() -> bool:
        logger.watch()
        return 5 in logger.exits[n:]
    return stopped


@pytest.mark.slow
def test_a_month_in_an_hour(fleet: Fleet, tmp_path: Path) -> None:
    need_root()
    seconds = float(os.environ.get("PYMB_MONTH_SECONDS", "1800"))
    sim = fleet.simulator("hub:250", "coolpro:40")
    broker = fleet.broker()
    sub = fleet.subscribe(broker, f"pymb/{NODE}/#", client_id="pymb-month-sub")
    clock = tmp_path / "faketime.rc"
    env = faketime_env(clock, "+0")
    with Tmpfs(tmp_path / "card", 64 << 10) as card:
        db = card.mountpoint / "data.sqlite"
        argv = [*PYMB, "log", "--tcp", sim.endpoint, "hub:250", "coolpro:40",
                "--interval", "0.1", "--out", str(db), "--quiet", "--mqtt", broker.url,
                "--mqtt-node", NODE, "--mqtt-drain", "120"]
        logger = Supervised(argv, env)
        # what happens, in turn, every `every` seconds over the first 70 % of the run;
        # the rest is calm but for a broker restart and a clock step (the last logger's
        # memory and descriptors are measured there)
        story = ["broker restart", "sigkill", "clock +1h", "broker stall", "disk full",
                 "clock back", "sigkill", "broker restart"]
        every = 0.7 * seconds / (2 * len(story))
        t0 = time.monotonic()
        done: list[str] = []
        filler: Path | None = None
        rss: list[tuple[float, int, int]] = []
        calm_events = ["broker restart", "clock +1h"]
        while (now := time.monotonic() - t0) < seconds:
            logger.watch()
            due = int(now / every)
            if due > len(done) and now < 0.7 * seconds:
                what = story[len(done) % len(story)]
                done.append(what)
                if what == "broker restart":
                    broker.stop()
                    time.sleep(min(5.0, every / 3))
                    broker.start()
                elif what == "broker stall":
                    assert broker.proc is not None
                    os.kill(broker.proc.pid, signal.SIGSTOP)
                    time.sleep(min(20.0, every / 2))  # past the keepalive: a silent link
                    os.kill(broker.proc.pid, signal.SIGCONT)
                elif what == "sigkill":
                    logger.kill()
                elif what == "clock +1h":
                    set_clock(clock, "+3600")
                elif what == "clock back":
                    set_clock(clock, "+0")
                elif what == "disk full":
                    filler = card.fill()
                    wait_until(_stopped_full(logger, len(logger.exits)),
                               "the logger to stop at the full disk", 120, every=0.2)
                    filler.unlink()  # freed: the next restart resumes
            elif now >= 0.7 * seconds and calm_events and \
                    now >= 0.7 * seconds + (3 - len(calm_events)) * 0.1 * seconds:
                what = calm_events.pop(0)
                done.append(what)
                if what == "broker restart":
                    broker.stop()
                    time.sleep(3)
                    broker.start()
                else:
                    set_clock(clock, "+7200")
            if now >= 0.72 * seconds and logger.proc is not None and logger.proc.poll() is None:
                rss.append((now, rss_kb(logger.proc.pid), open_fds(logger.proc.pid)))
            time.sleep(0.5)
        last_started = logger.started
        assert logger.stop() == 0
        assert logger.started == last_started  # no restart in the calm part
        want = db_ids(db)
        wait_until(lambda: set(plain_ids(sub.snapshot())) >= want,
                   "every sample of the database at the subscriber", 300)
        got = plain_ids(sub.snapshot())
        con = sqlite3.connect(db)
        try:
            integrity = con.execute("PRAGMA integrity_check").fetchone()[0]
            steps = con.execute("SELECT COUNT(*) FROM events WHERE kind = 'clock'").fetchone()[0]
        finally:
            con.close()
    first, last = rss[len(rss) // 4], rss[-1]
    print(f"\n{seconds:g} s: {len(want):,} samples in the database, {len(set(got)):,} "
          f"distinct ids received, {duplicates(got):,} duplicates; events {done}; "
          f"logger exits {logger.exits}, {logger.started} starts; clock steps {steps}; "
          f"last logger RSS {first[1]:,} -> {last[1]:,} kB, descriptors {first[2]} -> "
          f"{last[2]}")
    assert set(got) == want  # every sample, and only the database's
    assert integrity == "ok"
    assert logger.exits.count(-9) == done.count("sigkill")
    assert 5 in logger.exits
    assert steps >= 2
    assert last[1] - first[1] < 8 * 1024  # kB: flat, not growing with the run
    assert last[2] <= first[2] + 2
