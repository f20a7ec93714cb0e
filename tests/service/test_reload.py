"""SIGHUP to a logger without a controlling terminal (a service) reloads its
configuration: a bad one is refused and the run goes on; a good one is
taken by pymb executing itself again in the same process, and every sample
read before the reload is in the database. With a terminal, SIGHUP (the
terminal hung up) stops the run as before."""

from __future__ import annotations

import os
import re
import signal
from pathlib import Path

import pytest
from conftest import wait_until

pytest.register_assert_rewrite("servicekit")
from servicekit import NotifyListener, StderrLines, count_rows, start_log  # noqa: E402

from pymb.service.reload import Reload, controlling_terminal  # noqa: E402
from pymb.sim import SimulatorProcess  # noqa: E402

pytest_plugins = ["servicekit"]  # the coolpro fixture

CONFIG = """
[output]
path = "{db}"
commit_interval_s = 0.5

[[bus]]
tcp = "{endpoint}"
interval = 0.02

[[bus.device]]
type = "coolpro"
address = 40
name = "{name}"
"""


def _by_device(db: Path, name: str) -> int:
    return count_rows(db, "SELECT COUNT(*) FROM samples s JOIN devices d ON d.id = s.device_id "
                          f"WHERE d.name = '{name}'")


def test_sighup_reloads_without_losing_a_sample(coolpro: SimulatorProcess,
                                               tmp_path: Path) -> None:
    db, cfg = tmp_path / "data.sqlite", tmp_path / "pymb.toml"
    cfg.write_text(CONFIG.format(db=db, endpoint=coolpro.endpoint, name="psu-a"))
    name = f"@pymb-test-reload-{os.getpid()}"
    listener = NotifyListener(name)
    proc = start_log("--config", str(cfg), env={"NOTIFY_SOCKET": name})
    err = StderrLines(proc)
    try:
        wait_until(lambda: "READY=1" in listener.lines(), "READY=1",
                   alive=lambda: proc.poll() is None)
        wait_until(lambda: _by_device(db, "psu-a") >= 20, "samples of psu-a",
                   alive=lambda: proc.poll() is None)
        # a mistake in the new configuration: refused, the run goes on
        cfg.write_text("[[bus]\n")
        proc.send_signal(signal.SIGHUP)
        err.wait_for("service reload: SIGHUP: the new configuration is refused")
        before = _by_device(db, "psu-a")
        wait_until(lambda: _by_device(db, "psu-a") > before + 10, "psu-a logging on",
                   alive=lambda: proc.poll() is None)
        assert "RELOADING=1" not in listener.lines()
        # a good one: taken, in the same process
        cfg.write_text(CONFIG.format(db=db, endpoint=coolpro.endpoint, name="psu-b"))
        proc.send_signal(signal.SIGHUP)
        wait_until(lambda: _by_device(db, "psu-b") >= 20, "samples of psu-b after the reload",
                   alive=lambda: proc.poll() is None)
        lines = listener.lines()
        assert lines.count("READY=1") == 2
        assert lines.index("RELOADING=1") < len(lines) - 1 - lines[::-1].index("READY=1")
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(30) == 0, err.text()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        listener.close()
    # each run's summary counts what it logged; together they are what the database holds
    logged = [int(n.replace(",", "")) for n in re.findall(r"^logged ([\d,]+) samples",
                                                          err.text(), re.M)]
    assert len(logged) == 2, err.text()
    assert sum(logged) == count_rows(db)
    assert _by_device(db, "psu-a") == logged[0]


def test_reload_checks_before_it_stops() -> None:
    calls: list[int] = []

    def check() -> None:
        calls.append(1)
        if len(calls) == 1:
            from pymb.errors import InvalidArgument
            raise InvalidArgument("bad.toml: line 1: expected ']'")

    r = Reload(check)
    assert not r.due()  # no signal yet
    r.hangup()
    assert not r.due()
    assert r.refused == "bad.toml: line 1: expected ']'"
    assert not r.requested
    r.hangup()
    assert r.due()
    assert r.requested
    assert r.refused is None


def test_no_controlling_terminal_in_a_new_session() -> None:
    import subprocess
    import sys
    code = "from pymb.service.reload import controlling_terminal as c; print(c())"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         start_new_session=True, check=True).stdout
    assert out.strip() == "False"
    assert isinstance(controlling_terminal(), bool)
