"""Power cuts: a published sample id is never handed to another sample.

``pymb log --mqtt`` writes to an ext4 image on a loop device
(tests/disks.py). Each cut freezes the logger (SIGSTOP), copies the image
as the disk holds it at that instant (what was only in the page cache is
not in the copy), kills the logger and goes on from the copy: the next
logger runs on the copy mounted anew (ext4 replays its journal, SQLite its
WAL), as a board does after its power came back. One paho subscriber
records everything the broker delivered across all the runs.

The forwarder publishes each sample as soon as it is written, before its
commit; the writer hands out only ids under a high-water mark it committed
first (pymb.store.ids). The subscriber must never see one id with two
different samples, including after a cut that took back samples it had
received (those of the open batch); and with the default commit rule the
copy must hold every sample read up to 2 s before the cut (the loss bound
docs/reliability.md gives).
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

from pymb.store.ids import BLOCK  # noqa: E402

pytest_plugins = ["mqtt_broker"]
NODE = "gw-cut"
LOSS_BOUND = 2.0  #: seconds of samples a power cut may take back (docs/reliability.md)


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
    bound = LOSS_BOUND
    disk = LoopDisk(tmp_path / "disk0.img", tmp_path / "mnt0")
    worst = 0.0
    taken_back = 0  # samples the subscriber had that a cut took back
    try:
        for cut in range(cuts + 1):
            db = disk.mountpoint / "data.sqlite"
            before = set(plain_ids(sub.snapshot()))  # what earlier runs published
            seen = len(before)
            proc = fleet.log(sim.endpoint, db, "--mqtt", broker.url, "--mqtt-node", NODE,
                             commit=None)
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
            changed = [i for i, t, m in received if i in kept and kept[i] != (t, m)]
            assert not changed, f"cut {cut + 1}: ids {changed[:5]} hold other samples on the disk"
            lost = [(i, t) for i, t, _ in received if i not in kept and i not in before]
            taken_back += len(lost)
            newest = max(t for t, _ in kept.values())
            worst = max(worst, frozen_at - newest)
            assert frozen_at - newest <= bound, (
                f"cut {cut + 1}: the disk's newest sample is {frozen_at - newest:.2f} s "
                f"old, more than the loss bound ({bound:g} s)")
            old = [i for i, t in lost if t < frozen_at - bound]
            assert not old, f"cut {cut + 1}: published samples older than the loss bound " \
                            f"are not on the disk (ids {old[:5]}...)"
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
    # cuts took back what the subscriber had (the open batch): the test's point
    assert taken_back, "no cut took back a published sample: nothing was tested"
    return {"messages": len(got), "ids": len(by_id), "worst_loss_s": worst,
            "taken_back": taken_back}


def test_ids_restart_above_the_mark_after_a_kill_and_close_the_gap_on_a_clean_stop(
        fleet: Fleet, tmp_path: Path) -> None:
    """No root needed: SIGKILL takes back the open batch of a --mqtt run (the
    samples of the last second or so, published before their commit); the
    next run's ids start above the writer's mark, and a clean stop brings the
    mark down, so the run after it goes on without a gap."""
    broker = fleet.broker()
    sub = fleet.subscribe(broker, "pymb/#")
    sim = fleet.simulator("coolpro")
    db = tmp_path / "data.sqlite"

    def run(want: int, kill: bool) -> list[int]:
        seen = set(plain_ids(sub.snapshot()))
        proc = fleet.log(sim.endpoint, db, "--mqtt", broker.url, "--mqtt-node", NODE,
                         commit=None)
        # samples taken 3 s after the start: past the commits of the start's events
        after = time.time() + 3.0
        sub.wait_until(lambda m: sum(1 for i, t, _ in _samples(m)
                                     if i not in seen and t >= after) >= want, 60,
                       f"{want} more samples at the subscriber")
        if kill:
            proc.kill()
            proc.communicate(timeout=30)
        else:
            stop_log(proc)
        return sorted(set(plain_ids(sub.snapshot())) - seen)

    first = run(50, kill=True)
    assert first[0] == 1
    taken_back = set(first) - set(_rows(db))
    assert taken_back, "the kill took back no published sample: nothing was tested"
    second = run(50, kill=False)
    assert second[0] == first[0] + BLOCK, (first[:3], second[:3])
    assert set(second) <= set(_rows(db))  # a clean stop commits everything
    third = run(20, kill=False)
    assert third[0] == second[-1] + 1, (second[-3:], third[:3])


def test_power_cuts_never_reuse_a_published_id(fleet: Fleet, tmp_path: Path) -> None:
    _cuts(fleet, tmp_path, cuts=3, per_run=300)


@pytest.mark.slow
def test_many_power_cuts(fleet: Fleet, tmp_path: Path) -> None:
    _cuts(fleet, tmp_path, cuts=12, per_run=1000)
