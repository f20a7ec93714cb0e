"""What the polls the TCP loop's C part carried give the writer
(:class:`pymb.logger.tcpcarry.Carried`): one block a wait, each poll's
source and registers, and each poll's device answered where that is news,
also when the run's problems do not name it (a device whose bus of the same
name opened again: :meth:`Report.opened <pymb.logger.report.Report.opened>`
clears that name)."""

from __future__ import annotations

import queue
import threading
from pathlib import Path

from hostile_gateway import HX_MAP

from pymb.logger.config import load_config
from pymb.logger.stats import Stats
from pymb.logger.tcploop import TcpMapPoller
from pymb.store import Event, Sample
from pymb.store.block import PollBlock


def _armed(tmp: Path) -> tuple[TcpMapPoller, queue.Queue[list[Sample | Event | PollBlock]]]:
    """A loop of two buses (one device each, named as its bus), both armed
    with their one poll (no connection: nothing is sent or read here)."""
    (tmp / "hx.toml").write_text(HX_MAP)
    (tmp / "log.toml").write_text('maps = ["hx.toml"]\n' + "".join(
        f'[[bus]]\nname = "{n}"\ntcp = "127.0.0.1:{port}"\ninterval = 0\n'
        f'[[bus.device]]\ntype = "hx"\naddress = 1\nname = "{n}"\n'
        for n, port in (("a", 1), ("b", 2))))
    q: queue.Queue[list[Sample | Event | PollBlock]] = queue.Queue()
    p = TcpMapPoller(list(load_config(tmp / "log.toml").buses), q, threading.Event(), Stats())
    for c in p.conns:
        c.entry = e = c.entries[0]
        e.requests()
        assert e.table is not None
        p.arm(c, e.table, 1.0, 0.0)
    return p, q


def _carried(p: TcpMapPoller, done: list[int]) -> list[Sample | Event | PollBlock]:
    """What one wait that carried polls of ``done`` (their images 'A', 'B', ...) hands over."""
    size = len(p.conns[0].entries[0].image)
    assert p.cloop is not None
    for j in range(len(done)):  # (what the C part copied there)
        p.cloop.block[j * size:(j + 1) * size] = bytes([65 + j]) * size
    n = len(done)
    p.carried_block(done, [10.0 + j for j in range(n)], [j * size for j in range(n)])
    items: list[Sample | Event | PollBlock] = []
    while not p.report.out.empty():
        items += p.report.out.get_nowait()
    return items


def test_a_wait_of_well_devices_is_one_block_of_its_polls(tmp_path: Path) -> None:
    p, _ = _armed(tmp_path)
    (block,) = _carried(p, [1, 0, 1])
    assert isinstance(block, PollBlock)
    assert [s.device.name for s in block.sources] == ["b", "a", "b"]
    assert block.monos == [10.0, 11.0, 12.0]
    assert block.unread is None
    assert [s.data.wire for s in block.samples()] == [  # type: ignore[union-attr]
        b"AAAA", b"BBBB", b"CCCC"]


def test_a_device_that_failed_is_told_it_answered_once_its_poll_is_carried(
        tmp_path: Path) -> None:
    """Device ``b`` failed twice before its connection was armed, and its
    bus ``b`` opened since (the run's problems no longer name it): its first
    carried poll clears its failures, without an event (it was not
    offline); an offline device says ``online`` once, before the block."""
    p, _ = _armed(tmp_path)
    b = p.conns[1].units[0].health
    b.failures = 2
    p.disarm(p.conns[1])
    p.arm(p.conns[1], p.conns[1].entries[0].table, 1.0, 0.0)  # type: ignore[arg-type]
    assert not p.stats.problems
    (block,) = _carried(p, [0, 1, 1])
    assert isinstance(block, PollBlock)
    assert b.failures == 0
    a = p.conns[0].units[0].health
    a.failures, a.offline = 3, True
    p.disarm(p.conns[0])
    p.arm(p.conns[0], p.conns[0].entries[0].table, 1.0, 0.0)  # type: ignore[arg-type]
    got = _carried(p, [1, 0, 0])
    assert [type(i) for i in got] == [Event, PollBlock]
    assert isinstance(got[0], Event)
    assert (got[0].kind, got[0].message) == ("online", "a answers again")
    assert (a.failures, a.offline) == (0, False)
    assert [type(i) for i in _carried(p, [0, 1])] == [PollBlock]
