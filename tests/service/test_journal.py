"""Events as lines on stderr when it is not a terminal (the journal of a
service): they show while the logger runs, even with --quiet, rate-limited."""

from __future__ import annotations

import io
import signal
import time
from pathlib import Path

import pytest
from conftest import wait_until

pytest.register_assert_rewrite("servicekit")
from servicekit import StderrLines, start_log  # noqa: E402

from pymb.service.journal import EventLines, echoing, event_line  # noqa: E402
from pymb.sim import SimulatorProcess  # noqa: E402
from pymb.store import CsvSink, DeviceInfo, Event  # noqa: E402

pytest_plugins = ["servicekit"]  # the coolpro fixture


def _event(i: int) -> Event:
    dev = DeviceInfo("line1", "/dev/ttyUSB0", "coolpro", 41, "psu-b")
    return Event(time.time(), time.monotonic(), "line1", dev, "timeout", None, f"no reply {i}")


def test_one_line_per_event_naming_bus_device_and_kind() -> None:
    assert event_line(_event(1)) == "pymb log: line1/psu-b timeout: no reply 1"
    e = Event(0.0, 0.0, "mqtt", None, "mqtt", None, "lost the connection")
    assert event_line(e) == "pymb log: mqtt mqtt: lost the connection"


def test_a_storm_is_rate_limited_and_the_rest_counted() -> None:
    out = io.StringIO()
    lines = EventLines(out, burst=5, window=0.3)
    for i in range(20):
        lines(_event(i))
    other = Event(time.time(), time.monotonic(), "mqtt", None, "mqtt", None, "lost it")
    lines(other)  # another kind still shows
    assert out.getvalue().splitlines() == [*(event_line(_event(i)) for i in range(5)),
                                           event_line(other)]
    time.sleep(0.35)  # the next window
    lines(_event(99))
    tail = out.getvalue().splitlines()[6:]
    assert tail == ["pymb log: 15 more event(s) in the last 0.3 s are only in the events "
                    "table", event_line(_event(99))]


def test_a_terminal_gets_no_lines(tmp_path: Path) -> None:
    class Tty(io.StringIO):
        def isatty(self) -> bool:
            return True

    sink = CsvSink(str(tmp_path / "out.csv"))
    assert echoing(sink, Tty()) is sink
    assert echoing(sink, io.StringIO()) is not sink


def test_faults_reach_stderr_while_the_quiet_logger_runs(coolpro: SimulatorProcess,
                                                         tmp_path: Path) -> None:
    # coolpro:41 does not exist: its timeouts are events, and lines at once
    proc = start_log("--tcp", coolpro.endpoint, "coolpro:40", "coolpro:41", "--timeout", "0.1",
                     "--interval", "0.1", "--out", str(tmp_path / "d.sqlite"), "--quiet")
    err = StderrLines(proc)
    try:
        err.wait_for("pymb log: bus1/coolpro-41 timeout: ")
        assert proc.poll() is None  # seen while it runs, not in a summary
        proc.send_signal(signal.SIGTERM)
        proc.wait(30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    text = err.text()
    assert "coolpro-40 timeout" not in text
    assert wait_until(lambda: "coolpro-41 delivered no sample" in err.text(), "the problem line")
