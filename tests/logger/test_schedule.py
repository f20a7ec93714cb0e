"""The one schedule (:mod:`pymb.logger.schedule`), its rules on their own: a
clock is a number here, so each rule is checked at the exact instants that
matter (the runners that use it, a thread per bus and the TCP loop, are
tested end to end in the other files of this folder)."""

from __future__ import annotations

import itertools
import math
import queue
import threading

import pytest

from pymb import maps
from pymb.logger.report import Report
from pymb.logger.schedule import (
    BACKOFF_MAX,
    Agenda,
    Backoff,
    Health,
    Slot,
    reappeared,
)
from pymb.logger.stats import Stats
from pymb.store import Event, Sample
from pymb.store.block import PollBlock


def test_slots_are_drift_free_and_a_long_read_skips_whole_slots() -> None:
    s = Slot(Health.of_map("m", None, None), 1.0, group="fast")
    s.next_at = 100.0
    assert s.due(100.0)
    assert not s.due(99.99)
    assert s.advance(100.4) == 0  # read within its slot: the next at 101, not 101.4
    assert s.next_at == 101.0
    assert not s.due(100.99)
    assert s.due(101.0)
    assert s.wake(100.5) == 101.0
    assert s.advance(103.5) == 2  # slots 102 and 103 were overrun: skipped, counted
    assert s.next_at == 104.0
    assert s.skipped(2) == "2 poll slot(s) of 1 s skipped (m group fast)"
    assert s.advance(104.0 + 1.0) == 0  # ending exactly at the next slot: nothing skipped
    assert s.next_at == 105.0


def test_flat_out_is_always_due_and_never_skips() -> None:
    s = Slot(_backoff("hub", "hub-1"), 0.0)
    assert s.due(5.0)
    assert s.wake(5.0) == 5.0
    assert s.advance(1e6) == 0
    assert s.due(1e6)
    assert s.skipped(1) == "1 poll slot(s) of 0 s skipped (hub-1)"


def test_a_once_group_is_read_once_until_the_device_reappears() -> None:
    h = Health.of_map("m", None, None)
    once, fast = Slot(h, 0.0, True, "info"), Slot(h, 1.0, group="fast")
    assert once.due(0.0)
    assert once.wake(0.0) == 0.0
    assert once.advance(0.5) == 0
    assert not once.due(1e9)
    assert once.wake(1.0) == math.inf
    reappeared([once, fast])  # a connection opened again after a failure
    assert once.due(2.0)


def test_a_map_device_goes_offline_after_its_failures_and_is_tried_again() -> None:
    h = Health.of_map("m", 3, 10.0)
    s = Slot(h, 1.0)
    assert [h.failed(t) for t in (0.0, 1.0)] == ["", ""]
    assert s.due(2.0)
    assert not h.offline
    said = h.failed(2.0)
    assert said == "; offline after 3 failed poll(s), next try in 10 s"
    assert h.offline
    assert h.retry_at == 12.0
    s.next_at = 3.0
    assert not s.due(11.9)
    assert s.wake(3.0) == 12.0
    assert h.failed(12.0) == ""  # still offline: said once; the next try 10 s on
    assert h.retry_at == 22.0
    assert h.answered() is True  # back: the runner says "online"
    assert (h.failures, h.offline) == (0, False)
    assert h.answered() is False


def test_map_health_defaults() -> None:
    h = Health.of_map("m", None, None)
    assert h.failed(0.0) == "; offline after 1 failed poll(s), next try in 30 s"


def test_a_once_group_of_an_offline_device_waits_for_the_retry() -> None:
    h = Health.of_map("m", 1, 5.0)
    once = Slot(h, 0.0, True)
    h.failed(10.0)
    assert not once.due(12.0)
    assert once.wake(12.0) == 15.0
    assert once.due(15.0)


def _backoff(kind: str, name: str) -> Health:
    """A shipped device's health, as its map's ``[device.timing]`` sets it."""
    t = maps.builtin(kind).timing
    return Health.of_map(name, t.offline_after, t.offline_retry, t.backoff)


@pytest.mark.parametrize("kind", ["coolpro", "hub"])
def test_a_backoff_device_backs_off_doubling_after_ten_failures(kind: str) -> None:
    h = _backoff(kind, f"{kind}-1")
    said = [h.failed(float(t)) for t in range(10 + 8)]
    assert said[:9] == [""] * 9
    tail = said[9:]
    assert tail[:3] == ["; next try in 0.5 s", "; next try in 1 s", "; next try in 2 s"]
    assert tail[-1] == f"; next try in {BACKOFF_MAX:g} s"
    assert not h.offline  # backed off, not "offline": no online event when it answers
    assert h.answered() is False
    assert h.failed(100.0) == ""  # a new run of failures starts from nothing


def test_a_backoff_doubles_up_to_the_maps_offline_retry() -> None:
    h = Health.of_map("m", 1, 3.0, backoff=True)
    said = [h.failed(float(t)) for t in range(5)]
    assert said == ["; next try in 0.5 s", "; next try in 1 s", "; next try in 2 s",
                    "; next try in 3 s", "; next try in 3 s"]
    assert h.answered() is False  # no "online": it was backed off, not offline
    assert h.failed(10.0) == "; next try in 0.5 s"  # a new run starts from the first wait
    short = Health.of_map("m", 1, 0.2, backoff=True)
    assert short.failed(0.0) == "; next try in 0.2 s"


def test_a_failure_at_once_backs_off_at_once() -> None:
    h = _backoff("hub", "hub-1")
    assert h.failed(1.0, at_once=True) == "; next try in 0.5 s"
    s = Slot(h, 0.0)
    assert not s.due(1.2)
    assert s.wake(1.2) == 1.5


@pytest.mark.parametrize("n", [1, 5, 20])
def test_the_bus_backoff_doubles_to_its_cap_and_resets(n: int) -> None:
    b = Backoff()
    waits = [b.take() for _ in range(n)]
    assert waits[0] == 0.5
    assert all(w2 == min(2 * w1, BACKOFF_MAX) for w1, w2 in itertools.pairwise(waits))
    b.reset()
    assert b.take() == 0.5


def test_an_offline_device_whose_once_group_was_read_sleeps_until_it_reappears() -> None:
    """Its retry time passing is no reason to wake: nothing of it is due
    (a thread that woke then would wake again at once, for ever)."""
    h = Health.of_map("m", 1, 5.0)
    once = Slot(h, 0.0, True)
    h.failed(10.0)
    assert once.advance(10.0) == 0  # the failed read counts as the read
    assert not once.due(20.0)
    assert once.wake(20.0) == math.inf


def test_the_agenda_gives_the_due_slots_in_order_and_keeps_the_others() -> None:
    live, dead = Health.of_map("live", None, None), Health.of_map("dead", 1, 10.0)
    fast, slow, gone = Slot(live, 1.0), Slot(live, 5.0), Slot(dead, 1.0)
    agenda: Agenda[str] = Agenda()
    for s, name in ((fast, "fast"), (slow, "slow"), (gone, "gone")):
        s.next_at = 0.0
        agenda.put(s, name, 0.0)
    agenda.put(Slot(live, 0.0, True, read_once=True), "read", math.inf)  # never: not kept
    assert agenda.next() == 0.0
    dead.failed(0.0)  # offline until 10: its time came, not its slot's
    assert agenda.due(0.5) == ["fast", "slow"]
    assert agenda.next() == 10.0  # "gone", put back at its retry
    for s, name in ((fast, "fast"), (slow, "slow")):
        s.advance(0.6)
        agenda.put(s, name, s.wake(0.6))
    assert agenda.due(0.99) == []
    assert agenda.due(1.0) == ["fast"]
    assert agenda.due(100.0) == ["slow", "gone"]
    assert agenda.next() == math.inf


def test_a_skip_after_the_writer_took_its_last_items_is_neither_counted_nor_handed_over() -> None:
    """A poller left behind at the stop (in the middle of a long read) may
    find its slot overran: the run's summary counts skips as the stored events
    say them, so once the writer took its last items neither happens."""
    out: queue.Queue[list[Sample | Event | PollBlock]] = queue.Queue()
    stats = Stats()
    report = Report(out, stats)
    slot = Slot.every(0.05)
    report.skipped("bus1", slot, 3)
    (event,), = [out.get_nowait()]
    assert isinstance(event, Event)
    assert event.kind == "skipped"
    assert event.message.startswith("3 poll slot(s) of 0.05 s skipped")
    assert stats.skipped_slots == 3
    stats.close()
    report.skipped("bus1", slot, 14)
    assert out.empty()
    assert stats.skipped_slots == 3


def test_a_skip_waits_for_the_writer_without_holding_the_runs_counts() -> None:
    """A poller's hand-over waits while the writer's queue is full (it is
    bounded); the skip it is reporting then must not keep the run's counts
    locked: the writer takes that lock for its status line and at the stop
    (Stats.close) before it takes from the queue again, so a poller waiting
    with the lock held would stop the run for good."""
    putting = threading.Event()

    class Full(queue.Queue[list[Sample | Event | PollBlock]]):
        def put(self, item: list[Sample | Event | PollBlock], block: bool = True,
                timeout: float | None = None) -> None:
            putting.set()
            super().put(item, block, timeout)

    out = Full(maxsize=1)
    out.put([])  # the writer lags: the queue is full
    putting.clear()
    stats = Stats()
    report = Report(out, stats)
    poller = threading.Thread(target=report.skipped, args=("bus1", Slot.every(0.05), 2))
    poller.start()
    assert putting.wait(30)  # the poller waits on the full queue with its skip
    free = stats.lock.acquire(timeout=5)  # the status line's lock, Stats.close's
    if free:
        stats.lock.release()
    out.get()
    poller.join(30)
    assert free, "the poller held the run's counts while it waited for the writer"
    assert not poller.is_alive()
    (event,), = [out.get_nowait()]
    assert isinstance(event, Event)
    assert event.kind == "skipped"
    assert stats.skipped_slots == 2
