"""Power cuts: a published sample id is never handed to another sample.

``pymb log --mqtt`` writes to an ext4 image on a loop device
(tests/disks.py). Each cut freezes the logger (SIGSTOP), copies the image
as the disk holds it at that instant (what was only in the page cache is
not in the copy), kills the logger and goes on from the copy: the next
logger runs on the copy mounted anew (ext4 replays its journal, SQLite its
WAL), as a board does after its power came back. One paho subscriber
records everything the broker delivered across all the runs.

It must never see one id with two different samples; everything it
received before a cut must be in the copy; and the copy must hold every
sample read up to the documented commit interval before the cut.
"""

from __future__ import annotations

import json
import signal
import sqlite3
import time
from pathlib import Path
from typing import Any

import pytest

pytest.register_assert_rewrite("mqtt_broker", "disks")
from disks import LoopDisk, need_root  # noqa: E402
from mqtt_broker import Fleet, plain_ids, stop_log  # noqa: E402

from pymb.logger.config import MQTT_COMMIT_INTERVAL  # noqa: E402

pytest_plugins = ["mqtt_broker"]
NODE = "gw-cut"


def _samples(messages: list[tuple[str, bytes]]) -> list[tuple[int, float, float]]:
    """(id, time_utc, monotonic) of each plain data message."""
    out = []
    for topic, payload in messages:
        if topic.endswith("/status"):
            continue
        d = json.loads(payload)
        out.append((d["sample"], d["time_utc"], d["monotonic"]))
    return out


def _rows(db: Path) -> dict[int, tuple[float, float]]:
    con = sqlite3.connect(db)
    try:
        return {i: (t, m) for i, t, m in con.execute(
            "SELECT id, time_utc, monotonic FROM samples")}
    finally:
        con.close()


def _cuts(fleet: Fleet, tmp_path: Path, cuts: int, per_run: int) -> dict[str, Any]:
    need_root()
    broker = fleet.broker()
    sub = fleet.subscribe(broker, "pymb/#")
    sim = fleet.simulator("coolpro")
    bound = MQTT_COMMIT_INTERVAL  # forwarding: the broker waits no longer than this
    disk = LoopDisk(tmp_path / "disk0.img", tmp_path / "mnt0")
    worst = 0.0
    try:
        for cut in range(cuts + 1):
            db = disk.mountpoint / "data.sqlite"
            seen = len(plain_ids(sub.snapshot()))
            proc = fleet.log(sim.endpoint, db, "--mqtt", broker.url, "--mqtt-node", NODE)
            want = seen + per_run
            sub.wait_until(lambda m: len(plain_ids(m)) >= want, 60,  # noqa: B023
                           f"{per_run} more samples at the subscriber (run {cut + 1})")
            if cut == cuts:
                stop_log(proc)
                final = _rows(db)
                break
            proc.send_signal(signal.SIGSTOP)
            frozen_at = time.time()
            received = _samples(sub.snapshot())  # all published before the cut
            image = disk.power_cut(tmp_path / f"disk{cut + 1}.img")
            proc.kill()
            proc.communicate(timeout=30)
            disk.umount()
            disk = LoopDisk(image, tmp_path / f"mnt{cut + 1}", fresh=False)
            kept = _rows(disk.mountpoint / "data.sqlite")
            lost = [i for i, t, m in received if kept.get(i) != (t, m)]
            assert not lost, f"cut {cut + 1}: {len(lost)} published samples are not on the " \
                             f"disk (ids {lost[:5]}...)"
            newest = max(t for t, _ in kept.values())
            worst = max(worst, frozen_at - newest)
            assert frozen_at - newest <= bound + 1.0, (
                f"cut {cut + 1}: the disk's newest sample is {frozen_at - newest:.1f} s old, "
                f"more than the commit interval ({bound:g} s)")
    finally:
        disk.umount()
    got = _samples(sub.snapshot())
    by_id: dict[int, set[tuple[float, float]]] = {}
    for i, t, m in got:
        by_id.setdefault(i, set()).add((t, m))
    reused = {i: v for i, v in by_id.items() if len(v) > 1}
    assert not reused, f"{len(reused)} ids reached the subscriber with two samples: " \
                       f"{sorted(reused)[:5]}..."
    missing = set(final) - set(by_id)
    assert not missing, f"{len(missing)} samples of the database never reached the broker"
    return {"messages": len(got), "ids": len(by_id), "worst_loss_s": worst}


def test_power_cuts_never_reuse_a_published_id(fleet: Fleet, tmp_path: Path) -> None:
    _cuts(fleet, tmp_path, cuts=3, per_run=300)


@pytest.mark.slow
def test_many_power_cuts(fleet: Fleet, tmp_path: Path) -> None:
    _cuts(fleet, tmp_path, cuts=12, per_run=1000)
