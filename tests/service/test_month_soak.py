"""A month in an hour (``pymb bench --sections soak``, as a slow test):
``pymb log`` of a sensor hub and a CoolPro forwarding to mosquitto for
PYMB_MONTH_SECONDS (default 1800) while the broker restarts and stalls, the
logger is SIGKILLed, the disk (a small tmpfs) fills and is freed and the
wall clock steps (libfaketime), under a Restart=on-failure supervisor. The
subscriber ends with every id the database holds, and never one id with two
samples (duplicates counted; ids a kill or the full disk took back from the
batch they had been published from are counted too), the database is
intact, and the last logger's memory and descriptors stay flat.

    PYMB_MONTH_SECONDS=180 .venv/bin/python -m pytest -m slow tests/service/test_month_soak.py -s
"""

from __future__ import annotations

import pytest

pytest.register_assert_rewrite("disks")
from disks import need_root  # noqa: E402

from pymb.bench.soak import run_section  # noqa: E402


@pytest.mark.slow
def test_a_month_in_an_hour() -> None:
    need_root()  # the tmpfs that fills
    r = run_section(None, print)
    print(r)
    assert r["status"] == "ok", r
    assert r["left_out"] == []  # every disturbance happened
    assert r["lost"] == 0  # every sample of the database reached the subscriber
    assert r["reused"] == 0  # and no id came with two samples
    assert r["integrity"] == "ok"
    assert r["final_exit"] == 0
    assert sorted(set(r["exits"])) == [-9, 5]  # our SIGKILLs and the full disk only
    assert r["exits"].count(-9) == r["events"].count("sigkill")
    assert r["clock_steps"] >= 2
    first, last = r["rss_kb"]
    assert last - first < 8 * 1024  # kB: flat over the calm last 30 %
    assert r["fds"][1] <= r["fds"][0] + 2
