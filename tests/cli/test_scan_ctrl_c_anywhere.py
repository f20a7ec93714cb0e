"""Ctrl-C at any moment of ``pymb scan`` ends it quietly (exit 130, no traceback).

A real SIGINT, sent by the process to itself at the K-th line its main thread
runs once the scan's worker is started, for every K up to past one wait for
the worker's next event: so it lands at each point of that wait, including the
one between a lock's wait and its re-acquire, where a KeyboardInterrupt once
left ``queue.Queue``'s lock released and the scan ended in ``RuntimeError:
release unlocked lock``."""

from __future__ import annotations

import subprocess
import sys

import pytest
from conftest import PYMB_ENV

from pymb.sim import Simulator

# The child: for each K, one `pymb scan` (main()), SIGINT at the K-th line the
# main thread runs after the worker starts; prints "result K CODE SENT" or the traceback.
_CHILD = r"""
import os, signal, sys, threading, time, traceback
from pymb.cli import main

port, ks = sys.argv[1], [int(k) for k in sys.argv[2:]]
for k in ks:
    state = {"n": 0, "sent": False}
    before = set(threading.enumerate())

    def trace(frame, event, arg):
        if state["sent"]:
            return None
        if not any(t.name == "pymb-scan" for t in set(threading.enumerate()) - before):
            return trace
        if event == "line":
            state["n"] += 1
            if state["n"] == k:
                state["sent"] = True
                os.kill(os.getpid(), signal.SIGINT)
        return trace

    sys.settrace(trace)
    try:
        code = main(["scan", "--port", port, "--range", "1-3", "--timeout", "0.05",
                     "--confirm-timeout", "0.3"])
    except BaseException:
        sys.settrace(None)
        print(f"result {k} traceback", flush=True)
        traceback.print_exc()
        sys.exit(1)
    sys.settrace(None)
    end = time.monotonic() + 10  # the worker's end: the next scan opens the line again
    while set(threading.enumerate()) - before and time.monotonic() < end:
        time.sleep(0.02)
    print(f"result {k} {code} {state['sent']}", flush=True)
"""


@pytest.mark.ctrl_c
def test_scan_ctrl_c_at_any_line_of_the_main_thread_ends_quietly() -> None:
    ks = [str(k) for k in range(1, 41)]
    with Simulator(["coolpro:3"], seed=2) as sim:
        r = subprocess.run([sys.executable, "-c", _CHILD, sim.port, *ks], env=PYMB_ENV,
                           capture_output=True, text=True, timeout=600)
    assert "Traceback" not in r.stderr + r.stdout, r.stdout + r.stderr
    assert r.returncode == 0, r.stdout + r.stderr
    results = [line.split()[1:] for line in r.stdout.splitlines() if line.startswith("result ")]
    assert [k for k, *_ in results] == ks, r.stdout
    interrupted = [k for k, code, sent in results if sent == "True"]
    assert interrupted, r.stdout  # some K fell within the scan
    for k, code, sent in results:
        assert code == ("130" if sent == "True" else "0"), (k, r.stdout, r.stderr)
