"""The writer's handoff to a forwarder (pymb.store.handoff): the samples of
the open batch, as data, decode to what the file gives once committed; a
sample is never skipped, when the handoff let older ones go (past its limit)
the reader waits for the commit; the forwarder's cursor goes in with the
writer's batch; a batch rolled back takes back what it handed over."""

from __future__ import annotations

import sqlite3
import threading
from array import array
from pathlib import Path

import pytest
from conftest import wait_until

from pymb.devices import CoolProStatus, CoolProTelemetry, decode_hub
from pymb.errors import OutputError
from pymb.store import DeviceInfo, OnChange, Outbox, Sample, SqliteSink, StoredSample
from pymb.store.handoff import Handoff
from pymb.store.outbox import write_pending

_PSU = DeviceInfo("bus1", "/dev/null", "coolpro", 40, "psu")
_HUB = DeviceInfo("bus1", "/dev/null", "hub", 1, "hub-1")


def _psu(t: float) -> Sample:
    data = CoolProTelemetry(24.5, 2.45, 24.0, 2.41, 26.1, int(t), CoolProStatus(0),
                            array("H", [245, 245, 240, 241, 261, 0, int(t), 0]))
    return Sample(_PSU, 1_700_000_000 + t, t, data)


def _hub(t: float, bump: int) -> Sample:
    regs = array("H", [(i * 7) % 300 for i in range(700)])
    regs[0] += bump  # one channel's value moves
    return Sample(_HUB, 1_700_000_000 + t, t, decode_hub(regs))


def _ids(got: list[StoredSample]) -> list[int]:
    return [s.id for s in got]


def test_the_open_batch_handed_over_decodes_as_the_file(tmp_path: Path) -> None:
    """CoolPro samples and a hub stored by channel (on-change: the channels
    that moved, the rest not read), read from the handoff before their
    commit, equal the same samples read from the file after it."""
    db = tmp_path / "h.sqlite"
    sink = SqliteSink(db, on_change=OnChange(heartbeat=3600.0))
    handoff = Handoff()
    sink.publish_live(handoff)
    box = Outbox(str(db), handoff)
    for i in range(4):
        sink.write(_psu(float(i)))
        sink.write(_hub(float(i), i))
    live = box.samples_after(0, 100)
    n = len(live)
    assert n >= 5
    assert box.max_id() == n
    assert box.oldest_after(0) == (n, 1_700_000_000.0)
    assert box.latest("hub-1") == [s for s in live if s.device.name == "hub-1"][-1]
    assert [n for n, _, _ in box.devices()] == ["psu", "hub-1"]
    sink.commit()
    plain = Outbox(str(db))
    assert plain.samples_after(0, 100) == live
    con = sqlite3.connect(db)
    try:  # the hub's samples are stored by channel; the later ones, what moved only
        assert con.execute("SELECT COUNT(*) FROM samples WHERE registers IS NULL").fetchone()[
            0] >= 2
        assert con.execute("SELECT COUNT(*) FROM hub_changes").fetchone()[0] > 2
    finally:
        con.close()
    plain.close()
    box.close()
    sink.close()


def test_samples_not_held_past_the_limit_are_read_after_the_commit(tmp_path: Path) -> None:
    """At its limit the handoff holds no more samples of the open batch:
    the forwarder takes those it holds, then waits for the commit that puts
    the others in the file (none is skipped, no id is taken for a gap)."""
    db = tmp_path / "w.sqlite"
    sink = SqliteSink(db)
    handoff = Handoff(limit=4)
    sink.publish_live(handoff)
    box = Outbox(str(db), handoff)
    for i in range(3):
        sink.write(_psu(float(i)))
    assert _ids(box.samples_after(0, 100)) == [1, 2, 3]
    for i in range(3, 9):
        sink.write(_psu(float(i)))  # 1..4 held (1..3 go at the next read past them)
    assert _ids(box.samples_after(3, 100)) == [4]
    assert box.samples_after(4, 100) == []  # 5..9 are not held
    assert box.durable() == 0  # the backlog's gap rule waits too
    backlog = box.oldest_after(4)
    assert backlog is not None
    assert backlog[0] == 5
    newest = box.latest("psu")
    assert newest is not None
    assert newest.id == 9
    sink.commit()
    assert _ids(box.samples_after(4, 100)) == [5, 6, 7, 8, 9]
    assert box.durable() == 9
    for i in range(9, 11):
        sink.write(_psu(float(i)))  # held again after the commit
    assert _ids(box.samples_after(9, 100)) == [10, 11]
    box.close()
    sink.close()
    assert not box.live


def test_the_cursor_goes_in_with_the_writers_batch(tmp_path: Path) -> None:
    """A cursor set beside a running writer waits for the writer's next
    batch (no commit of its own); once the writer closed, it is written
    on the outbox's own connection."""
    db = tmp_path / "c.sqlite"
    sink = SqliteSink(db)
    handoff = Handoff()
    sink.publish_live(handoff)
    box = Outbox(str(db), handoff)
    sink.write(_psu(0.0))
    box.set_cursor("dest", 1)
    assert Outbox(str(db)).cursor_or_none("dest") is None
    sink.in_batch(lambda con: write_pending(con, handoff, closing=True), False)
    sink.close()
    assert Outbox(str(db)).cursor("dest") == 1
    box.set_cursor("dest", 2)  # the writer is gone: its own connection
    assert Outbox(str(db)).cursor("dest") == 2
    box.close()


def test_a_state_not_yet_committed_is_still_the_one_remembered(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A Sparkplug bdSeq set while the writer does not commit within the
    wait (a slow card's fsync) is what the next connection reads: two
    connections never carry the same bdSeq."""
    import pymb.store.outbox as outbox
    monkeypatch.setattr(outbox, "STATE_COMMIT_WAIT", 0.2)
    db = tmp_path / "bd.sqlite"
    sink = SqliteSink(db)
    h = Handoff()
    sink.publish_live(h)
    sink.write(_psu(0.0))
    sink.commit()
    box = Outbox(str(db), h)
    seqs = []
    for _ in range(2):  # what SparkplugProfile.new_connection does, twice, no commit between
        last = box.state("bdSeq")
        seqs.append(0 if last is None else (last + 1) % 256)
        box.set_state("bdSeq", seqs[-1])
    assert seqs == [0, 1]
    # the writer's next batch (as its owner runs it) takes the last one: the file says it now
    sink.in_batch(lambda con: write_pending(con, h, closing=False), False)
    sink.commit()
    assert Outbox(str(db)).state("bdSeq") == 1
    assert box.state("bdSeq") == 1
    sink.close()
    box.close()


def _disk_full(con: sqlite3.Connection) -> None:
    """What a command desk's record meets on a full disk, inside the writer's batch."""
    raise sqlite3.OperationalError("database or disk is full")


def _names(got: list[StoredSample]) -> list[tuple[int, str]]:
    return [(s.id, s.device.name) for s in got]


def test_a_batch_rolled_back_takes_back_what_it_handed_over(tmp_path: Path) -> None:
    """A sample of one device is read from the open batch; the batch is
    rolled back (a write command's record fails inside it); the next batch
    gives the rolled-back device's id to another device. What the forwarder
    reads then is what the file has: the new device's sample under its own
    name, nothing of the rolled-back one; the forwarder's cursor taken by
    the lost batch goes in with the next one."""
    db = tmp_path / "rb.sqlite"
    sink = SqliteSink(db)
    handoff = Handoff()
    sink.publish_live(handoff)
    box = Outbox(str(db), handoff)
    sink.write(_psu(0.0))
    assert _names(box.samples_after(0, 100)) == [(1, "psu")]  # published before the commit
    box.set_cursor("dest", 1)
    sink.in_batch(lambda con: write_pending(con, handoff), False)  # the cursor, in the batch
    with pytest.raises(OutputError):
        sink.in_batch(_disk_full, True)
    assert box.samples_after(0, 100) == []
    assert box.latest("psu") is None
    assert box.devices() == []
    assert box.oldest_after(0) is None
    assert box.max_id() == 0
    sink.write(_hub(1.0, 0))
    sink.write(_hub(2.0, 1))
    live = box.samples_after(1, 100)
    assert _names(live) == [(2, "hub-1"), (3, "hub-1")]  # id 1 is a gap: never given again
    # a reader not past the gap takes them at once or after the commit, never more
    assert _names(box.samples_after(0, 100)) in ([], _names(live))
    latest = box.latest("hub-1")
    assert latest is not None
    assert latest.id == 3
    assert box.latest("psu") is None
    assert [n for n, _, _ in box.devices()] == ["hub-1"]
    assert box.oldest_after(0) == (2, 1_700_000_001.0)
    sink.in_batch(lambda con: write_pending(con, handoff), False)
    sink.commit()
    con = sqlite3.connect(db)
    try:  # the id the rolled-back device had is the new device's
        assert con.execute("SELECT id, name FROM devices").fetchall() == [(1, "hub-1")]
    finally:
        con.close()
    assert box.samples_after(0, 100) == live
    plain = Outbox(str(db))
    assert plain.samples_after(0, 100) == live
    assert plain.cursor_or_none("dest") == 1
    plain.close()
    box.close()
    sink.close()


def test_a_state_in_a_batch_rolled_back_is_not_durable(tmp_path: Path) -> None:
    """A Sparkplug bdSeq taken into a batch that is then rolled back is
    not said durable at the next commit before it is written again: it goes
    in with that next batch."""
    db = tmp_path / "st.sqlite"
    sink = SqliteSink(db)
    h = Handoff()
    sink.publish_live(h)
    box = Outbox(str(db), h)
    done: list[bool] = []
    t = threading.Thread(target=lambda: done.append(h.put_state("bdSeq", 7, 30)))
    t.start()
    wait_until(h.commit_wanted.is_set, "the state handed over")
    sink.in_batch(lambda con: write_pending(con, h), False)
    with pytest.raises(OutputError):
        sink.in_batch(_disk_full, True)
    assert h.commit_wanted.is_set()  # still to be written
    sink.commit()  # a commit of a batch that does not have it
    assert not done
    assert Outbox(str(db)).state("bdSeq") is None
    assert box.state("bdSeq") == 7
    sink.in_batch(lambda con: write_pending(con, h), False)
    sink.commit()
    t.join(30)
    assert done == [True]
    assert Outbox(str(db)).state("bdSeq") == 7
    box.close()
    sink.close()
