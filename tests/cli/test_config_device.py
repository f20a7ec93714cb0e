"""``pymb config`` changes the settings of a device read through the
CoolPro's view (its map's ``[device] view``): any other device is a one-line
usage error before any I/O (the port is never opened)."""

from __future__ import annotations

import signal
import subprocess

import pytest
from conftest import PYMB, PYMB_ENV, run_pymb

from pymb.sim import SimulatorProcess


def test_pymb_config_of_another_device_is_a_one_line_error() -> None:
    for device, kind in (("hub:7", "hub"), ("eastron-sdm120", "eastron-sdm120")):
        r = run_pymb("config", device, "--port", "/nonexistent/tty", "--set-address", "5")
        assert r.returncode == 2, r.stderr
        assert r.stdout == ""
        assert r.stderr == ("pymb config: pymb config changes a CoolPro's settings, "
                            f"not a {kind}'s: pymb config coolpro[:ADDRESS] ...\n")


@pytest.mark.ctrl_c
@pytest.mark.timing  # the SIGINT may land between the step's line and its write going out
@pytest.mark.parametrize(("after", "said"), [
    ("CoolPro at 40", "the new settings may or may not have been stored; stored settings "
                      "take effect at the device's next reset (pymb config coolpro:40 reads "
                      "them)"),
    ("written: address 40 -> 42", "the reset may or may not have been sent: the CoolPro "
                                  "answers at address 42, 9600 bit/s once reset"),
    ("reset sent", "the reset was sent: the CoolPro answers at address 42, 9600 bit/s once "
                   "it restarts"),
])
def test_ctrl_c_after_a_write_went_out_says_what_the_device_may_hold(after: str,
                                                                     said: str) -> None:
    """Ctrl-C while a CoolPro slow to answer is being changed: exit 130 and one
    line saying what it may now hold, not a silence after which it moves to
    another address at its next power cycle."""
    with SimulatorProcess(["coolpro:40,delay=1", "--tcp", "127.0.0.1:0"], quiet=True) as sim:
        proc = subprocess.Popen(
            [*PYMB, "config", "coolpro:40", "--tcp", sim.endpoint, "--set-address", "42",
             "--reset", "--yes", "--timeout", "30"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
            env={**PYMB_ENV, "PYTHONUNBUFFERED": "1"})
        assert proc.stdout is not None
        for line in proc.stdout:  # the step printed: the next request is out, its reply late
            if line.startswith(after):
                break
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
    assert proc.returncode == 130
    assert err == f"pymb config: interrupted; {said}\n"
