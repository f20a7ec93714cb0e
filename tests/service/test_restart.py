"""What ``Restart=on-failure`` does, without systemd: the exact ExecStart
command line of contrib/pymb.service, with contrib/pymb.toml adapted to a
temporary directory (the database, the serial port's by-id name as a link to
a simulated bus, a broker on a free port), run, SIGKILLed, run again. The
second run resumes on the same database: its ids continue, the forwarder's
cursor continues (nothing at or below it is sent again), every sample
reaches the subscriber once or, past the cursor, twice with the same
content; samples the kill took back from the database (published before
their commit) may have reached it too, and their ids are never used again.
The exit codes are those the unit's RestartPreventExitStatus expects: a
configuration mistake is not restarted, a storage fault is."""

from __future__ import annotations

import configparser
import shlex
import signal
import sqlite3
import subprocess
from collections import defaultdict
from contextlib import closing
from pathlib import Path

import pytest

pytest.register_assert_rewrite("mqtt_broker")
from conftest import PYMB, PYMB_ENV, ROOT, wait_until  # noqa: E402
from mqtt_broker import Fleet, db_ids, plain_ids  # noqa: E402

from pymb.cli import EXIT_USAGE  # noqa: E402
from pymb.sim import SimulatorProcess  # noqa: E402

pytest_plugins = ["mqtt_broker"]  # the fixtures: fleet, ...

UNIT = ROOT / "contrib" / "pymb.service"
TOML = ROOT / "contrib" / "pymb.toml"
EXIT_STORAGE = 5


def _service() -> configparser.SectionProxy:
    unit = configparser.ConfigParser(strict=False, interpolation=None)
    unit.optionxform = str  # type: ignore[assignment,method-assign]
    unit.read_string(UNIT.read_text())
    return unit["Service"]


def _replace_once(text: str, old: str, new: str) -> str:
    assert text.count(old) == 1, f"contrib/pymb.toml no longer has {old!r} once"
    return text.replace(old, new)


class Service:
    """The unit's ExecStart, its /etc and /var/lib in a temporary directory."""

    def __init__(self, tmp: Path, bus: str, broker_port: int) -> None:
        self.state = tmp / "var" / "lib" / "pymb"  # StateDirectory=pymb
        self.state.mkdir(parents=True)
        self.db = self.state / "data.sqlite"
        self.config = tmp / "etc" / "pymb" / "pymb.toml"
        self.config.parent.mkdir(parents=True)
        text = TOML.read_text()
        text = _replace_once(text, '"/var/lib/pymb/data.sqlite"', f'"{self.db}"')
        text = _replace_once(text, '"/dev/serial/by-id/', f'"{bus}/')
        text = _replace_once(text, '"mqtt://broker.plant.example:1883"',
                             f'"mqtt://127.0.0.1:{broker_port}"')
        self.config.write_text(text)
        argv = shlex.split(_service()["ExecStart"])
        assert argv[0] == "/opt/pymb/bin/pymb"
        assert argv.count("/etc/pymb/pymb.toml") == 1
        self.argv = [*PYMB, *[str(self.config) if a == "/etc/pymb/pymb.toml" else a
                              for a in argv[1:]]]

    def start(self, fleet: Fleet) -> subprocess.Popen[str]:
        """One start, as systemd makes it (WorkingDirectory=%S/pymb, no terminal)."""
        proc = subprocess.Popen(self.argv, cwd=self.state, stdin=subprocess.DEVNULL,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                env=PYMB_ENV)
        fleet.children.append(proc)
        return proc

    def cursor(self) -> int:
        """The forwarder's cursor as committed (0: none yet)."""
        try:
            with closing(sqlite3.connect(f"file:{self.db}?mode=ro", uri=True)) as con:
                rows = con.execute("SELECT sample_id FROM outbox").fetchall()
        except sqlite3.OperationalError:
            return 0  # not made yet
        assert len(rows) <= 1, rows  # one receiver, one cursor
        return int(rows[0][0]) if rows else 0


def test_a_killed_service_resumes_where_it_was(fleet: Fleet, tmp_path: Path) -> None:
    prevent = {int(x) for x in _service()["RestartPreventExitStatus"].split()}
    assert _service()["Restart"] == "on-failure"
    by_id = tmp_path / "serial" / "by-id"
    by_id.mkdir(parents=True)
    port = by_id / "usb-FTDI_FT232R_USB_UART_A10K5ABC-if00-port0"
    sim = SimulatorProcess(["coolpro:40", "hub:250", "--link", str(port)], quiet=True).start()
    fleet.simulators.append(sim)
    broker = fleet.broker()
    sub = fleet.subscribe(broker, "pymb/board-7/#")
    service = Service(tmp_path, str(by_id), broker.port)

    first = service.start(fleet)
    wait_until(lambda: len(plain_ids(sub.snapshot())) >= 40, "40 samples live", 60,
               alive=lambda: first.poll() is None)
    wait_until(lambda: service.cursor() >= 20, "the cursor committed past 20", 60,
               alive=lambda: first.poll() is None)
    first.send_signal(signal.SIGKILL)
    first.communicate(timeout=30)
    # Killed by a signal: a failure to systemd, restarted (on-failure).
    assert first.returncode == -signal.SIGKILL
    before = db_ids(service.db)
    cursor = service.cursor()
    assert before
    assert 20 <= cursor <= max(before)

    second = service.start(fleet)
    wait_until(lambda: max(plain_ids(sub.snapshot())) > max(before) + 30,
               "30 samples of the restarted service live", 60,
               alive=lambda: second.poll() is None)
    second.send_signal(signal.SIGTERM)  # systemctl stop
    _, err = second.communicate(timeout=60)
    assert second.returncode == 0, err

    after = db_ids(service.db)
    assert before <= after  # the same database, nothing committed lost
    assert min(after - before) > max(before)  # its ids continue above the first run's
    final = service.cursor()
    assert final == max(after)  # a clean stop sent everything (the broker has it) ...
    # ... and the broker hands each sample on to the subscriber in its own time:
    # what is guaranteed is that every one arrives, not that it has when the
    # service exits.
    sub.wait_until(lambda m: after <= set(plain_ids(m)), 60,
                   f"the subscriber to receive every sample up to {final}")
    payloads: dict[int, set[bytes]] = defaultdict(set)
    counts: dict[int, int] = defaultdict(int)
    for topic, payload in sub.snapshot():
        if not topic.endswith(("/status", "/meta")):
            (sample,) = plain_ids([(topic, payload)])
            payloads[sample].add(payload)
            counts[sample] += 1
    got = set(payloads)
    assert after <= got  # every sample in the database reached the broker
    # The others can only be the killed run's last samples: published from their
    # open batch before its commit and lost with it (docs/reliability.md), their
    # ids above the first run's last committed one and below the second run's
    # first, which skipped them instead of giving them to other samples.
    lost = got - after
    assert all(max(before) < i < min(after - before) for i in lost), sorted(lost)
    assert all(len(p) == 1 for p in payloads.values())  # one id, one sample
    again = {i for i, n in counts.items() if n > 1}
    assert all(i > cursor for i in again), sorted(again)  # the cursor continued

    # The exit codes RestartPreventExitStatus sorts: a configuration mistake
    # (exit 2) is not restarted ...
    assert EXIT_USAGE in prevent
    good = service.config.read_text()
    service.config.write_text(good.replace("[output]\n", "[output]\nbogus = 1\n", 1))
    bad = service.start(fleet)
    _, err = bad.communicate(timeout=60)
    assert bad.returncode == EXIT_USAGE, err
    assert "bogus" in err
    # ... a storage fault (exit 5: the disk not mounted yet) is, and the
    # restart after it resumes.
    assert EXIT_STORAGE not in prevent
    service.config.write_text(good.replace(str(service.db),
                                           str(tmp_path / "unmounted" / "data.sqlite")))
    missing = service.start(fleet)
    _, err = missing.communicate(timeout=60)
    assert missing.returncode == EXIT_STORAGE, err
    assert "does not exist" in err
