"""The one TCP loop's pipelined polls (:mod:`pymb.logger.tcploop`, the C
core's sans-I/O master through :mod:`pymb._native.master`): a poll's
requests go out in one write and the loop waits for all of their replies at
once, yet a reply that is not the expected one (an exception, a reply in
pieces, one never sent) is handled as the loop handles it one request at a
time."""

from __future__ import annotations

import socket
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from hostile_gateway import Handed, Hostile, Request, Script, good, poll

from pymb._native.master import Master, PollTable
from pymb.logger.tcpunits import PollRequest
from pymb.maps.planner import Request as Planned

#: two more points, too far apart to be read in one request: a poll of 3
#: requests (addresses 0, 300 and 600)
FAR = "".join(f'[[point]]\nname = "p{a}"\naddress = {a}\ntype = "u16"\n' for a in (300, 600))
#: register -> value of unit 1 (the gateway's rule: 100 x unit + address)
WANT = {0: 100, 1: 101, 300: 400, 600: 700}
PIPELINED = "timeout = 0.5\ninterval = 0.05\npipeline = 4\n"


def _exception(req: Request, code: int) -> bytes:
    tid, unit, fc, _, _ = req
    return tid.to_bytes(2, "big") + b"\x00\x00\x00\x03" + bytes((unit, fc | 0x80, code))


def _second(what: str) -> Script:
    """The request for register 300 (the 2nd of each poll) answered with
    ``what`` ("02", "04": that exception; "none": nothing), every other one
    right."""
    def script(n: int, req: Request, conn: socket.socket) -> bytes | None:
        if req[3] != 300:
            return good(*req)
        return None if what == "none" else _exception(req, int(what, 16))
    return script


def _dribble(n: int, req: Request, conn: socket.socket) -> None:
    for b in good(*req):
        conn.send(bytes((b,)))
        time.sleep(0.001)


def _poll(tmp_path: Path, script: Script, until: Callable[[Handed], bool],
          **kw: Any) -> Handed:
    """``poll`` of one hostile gateway running ``script``, closed afterwards."""
    gw = Hostile(script)
    try:
        return poll(tmp_path, [gw.port], until, **kw)
    finally:
        gw.close()


def _registers(got: object) -> set[tuple[int, ...]]:
    return {tuple(s.data.registers[a] for a in WANT)  # type: ignore[union-attr]
            for s in got.samples}  # type: ignore[attr-defined]


def test_pipelined_replies_written_a_byte_at_a_time_are_read_whole(tmp_path: Path) -> None:
    """Each reply of a pipelined poll comes a byte at a time: the loop keeps
    the part that came and reads every poll whole."""
    got = _poll(tmp_path, _dribble, lambda h: len(h.samples) >= 5, bus=PIPELINED,
                   points=FAR)
    assert [k for k in got.kinds() if k not in ("connect", "skipped")] == []
    assert _registers(got) == {tuple(WANT.values())}


def test_a_refused_point_in_a_pipelined_poll_is_replanned_in_the_same_poll(
        tmp_path: Path) -> None:
    """Exception 02 to the 2nd of a poll's three requests, the others
    answered: the point reads ``unsupported`` in that same poll's sample and
    the next polls leave it out; nothing times out."""
    got = _poll(tmp_path, _second("02"), lambda h: len(h.samples) >= 5, bus=PIPELINED,
                   points=FAR)
    assert [k for k in got.kinds() if k not in ("connect", "skipped")] == []
    assert all(s.data.unsupported == ("p300",) for s in got.samples)  # type: ignore[union-attr]
    for s in got.samples:
        regs = s.data.registers  # type: ignore[union-attr]
        assert (regs[0], regs[1], regs[600]) == (100, 101, 700)
    assert got.stats.unsupported.get("hx-1") == {"p300"}


def test_an_exception_in_a_pipelined_poll_fails_that_poll_only(tmp_path: Path) -> None:
    """Exception 04 to the 2nd request of every poll: each poll fails with an
    ``exception`` event naming that request, none stores a sample, the
    replies to the 3rd request are skipped, nothing times out."""
    got = _poll(tmp_path, _second("04"), lambda h: len(h.events) >= 4, bus=PIPELINED,
                   points=FAR)
    kinds = [k for k in got.kinds() if k not in ("connect", "skipped", "offline", "online")]
    assert set(kinds) == {"exception"}, kinds
    first = next(e for e in got.events if e.kind == "exception")
    assert "address=300, count=1" in first.message
    assert "exception 04" in first.message
    assert got.samples == []


def test_a_request_never_answered_times_out_by_name(tmp_path: Path) -> None:
    """The 2nd of a poll's three requests is never answered: the replies to
    the 1st and the 3rd are read, and the timeout names the one missing."""
    got = _poll(tmp_path, _second("none"), lambda h: len(h.events) >= 2, bus=PIPELINED,
                   points=FAR)
    first = next(e for e in got.events if e.kind == "timeout")
    assert "address=300, count=1" in first.message, first.message
    assert got.samples == []


def _every_other() -> Script:
    """Every other poll's 2nd request answered with exception 04."""
    seen = [0]

    def script(n: int, req: Request, conn: socket.socket) -> bytes | None:
        if req[3] == 300:
            seen[0] += 1
            if seen[0] % 2:
                return _exception(req, 4)
        return good(*req)
    return script


@pytest.mark.timing
def test_an_exception_reply_is_read_long_before_the_timeout(tmp_path: Path) -> None:
    """An exception reply is shorter than the reply the loop waits for (it
    wakes once for a poll's replies): it is read within milliseconds, not at
    the 2 s timeout; the next poll follows at its interval."""
    got = _poll(tmp_path, _every_other(), lambda h: len(h.samples) >= 6,
                   bus="timeout = 2\ninterval = 0.05\npipeline = 4\n", points=FAR,
                   within=10.0)
    faults = [e for e in got.events if e.kind == "exception"]
    assert len(faults) >= 5
    for e in faults[1:]:  # its poll began 0.05 s after the last sample; waited out: 2 s
        before = max(s.monotonic for s in got.samples if s.monotonic < e.monotonic)
        assert e.monotonic - before < 0.5


@pytest.mark.parametrize("pipeline", [1, 2])
def test_a_poll_longer_than_the_pipeline_never_waits_for_its_timeout(
        tmp_path: Path, pipeline: int) -> None:
    """A poll of three requests, one or two at a time, flat out with a 2 s
    timeout (its last reply longer than its first): each reply is read as it
    comes, every poll makes its sample."""
    last_big = FAR.replace('address = 600\ntype = "u16"', 'address = 600\ntype = "f64"')
    got = _poll(tmp_path, lambda n, req, conn: good(*req), lambda h: len(h.samples) >= 30,
                   bus=f"timeout = 2\ninterval = 0\npipeline = {pipeline}\n",
                   points=last_big, within=10.0)
    assert got.kinds() == ["connect"]
    assert len(got.samples) >= 30
    assert _registers(got) == {tuple(WANT.values())}


def _third_every_other() -> Script:
    """Every other poll's 3rd request (register 600) answered with exception 04."""
    seen = [0]

    def script(n: int, req: Request, conn: socket.socket) -> bytes | None:
        if req[3] == 600:
            seen[0] += 1
            if seen[0] % 2:
                return _exception(req, 4)
        return good(*req)
    return script


@pytest.mark.timing
def test_an_exception_among_the_last_replies_of_a_poll_longer_than_the_pipeline(
        tmp_path: Path) -> None:
    """A poll of three requests two at a time: once its last request is out,
    the loop wakes once for the rest of its replies, yet an exception among
    them (shorter than the reply it stands for) is read within milliseconds,
    not at the 2 s timeout."""
    got = _poll(tmp_path, _third_every_other(), lambda h: len(h.samples) >= 6,
                bus="timeout = 2\ninterval = 0.05\npipeline = 2\n", points=FAR, within=10.0)
    faults = [e for e in got.events if e.kind == "exception"]
    assert len(faults) >= 5
    assert all("address=600, count=1" in e.message for e in faults)
    for e in faults[1:]:  # its poll began 0.05 s after the last sample; waited out: 2 s
        before = max(s.monotonic for s in got.samples if s.monotonic < e.monotonic)
        assert e.monotonic - before < 0.5
    assert _registers(got) == {tuple(WANT.values())}


def test_the_last_replies_of_a_poll_longer_than_the_pipeline_in_pieces(
        tmp_path: Path) -> None:
    """Replies a byte at a time to a poll of three requests two at a time:
    the part of a reply that came counts against the rest the loop waits
    for, and every poll is read whole."""
    got = _poll(tmp_path, _dribble, lambda h: len(h.samples) >= 5,
                bus="timeout = 2\ninterval = 0\npipeline = 2\n", points=FAR)
    assert [k for k in got.kinds() if k not in ("connect", "skipped")] == []
    assert _registers(got) == {tuple(WANT.values())}


def test_a_poll_table_refuses_a_reply_that_would_not_fit_its_image() -> None:
    r = Planned("holding", 10, 4, (0,), ((0,),), 0)
    ok = PollTable([PollRequest(r, 0)], 1, bytearray(8))
    m = Master()
    m.reset(0xFFFF)
    assert m.frames(ok, 0, 1) == 12
    assert bytes(m.out[:12]) == bytes.fromhex("ffff 0000 0006 01 03 000a 0004".replace(" ", ""))
    assert m.in_flight == 1
    with pytest.raises(ValueError, match="do not fit"):
        PollTable([PollRequest(r, 2)], 1, bytearray(8))
    with pytest.raises(ValueError, match="not in a poll of 1"):
        m.frames(ok, 1, 1)


#: flat out: each poll's requests go out as the last poll's replies are in
FLAT_OUT = "timeout = 0.5\ninterval = 0\npipeline = 4\n"


def _from_poll(k: int, what: str) -> Script:
    """Every request answered right, but the one for register 300 from the
    ``k``-th poll on (``what`` "02": exception 02 from then on; "04": that
    poll only, exception 04)."""
    seen = [0]

    def script(n: int, req: Request, conn: socket.socket) -> bytes | None:
        if req[3] != 300:
            return good(*req)
        seen[0] += 1
        if seen[0] < k or (what == "04" and seen[0] > k):
            return good(*req)
        return _exception(req, int(what, 16))
    return script


def test_flat_out_polls_follow_each_other_whole(tmp_path: Path) -> None:
    """Flat out and pipelined, each poll's requests are framed in the take
    that read the last poll's replies and sent at once: every sample whole,
    one after the other, no event but the connect. The loop's C part hands
    them over in blocks, each poll stamped when it was read."""
    got = _poll(tmp_path, lambda n, req, conn: good(*req), lambda h: len(h.samples) >= 60,
                bus=FLAT_OUT, points=FAR)
    assert got.kinds() == ["connect"]
    assert _registers(got) == {tuple(WANT.values())}
    times = [s.monotonic for s in got.samples]
    assert times == sorted(times)
    assert len(set(times)) == len(times)
    assert got.blocks
    for b in got.blocks:
        assert abs(b.clock - (time.time() - time.monotonic())) < 1.0
        assert [s.time_utc - s.monotonic for s in b.samples()] == pytest.approx([b.clock] * len(b))


def test_a_point_refused_while_flat_out_is_replanned_in_that_poll(tmp_path: Path) -> None:
    """Flat out, the device refuses register 300 (exception 02) from its 20th
    poll on: that poll's sample already reads the point ``unsupported`` and
    so do the ones after it; the polls before it read it; nothing fails."""
    got = _poll(tmp_path, _from_poll(20, "02"), lambda h: len(h.samples) >= 40,
                bus=FLAT_OUT, points=FAR)
    assert got.kinds() == ["connect"]
    gone = [s.data.unsupported for s in got.samples]  # type: ignore[union-attr]
    assert gone == [()] * 19 + [("p300",)] * (len(gone) - 19)
    for s in got.samples:
        regs = s.data.registers  # type: ignore[union-attr]
        assert (regs[0], regs[1], regs[600]) == (100, 101, 700)


def test_an_exception_while_flat_out_fails_that_poll_only(tmp_path: Path) -> None:
    """Flat out, the 10th poll's 2nd request is answered with exception 04:
    that poll fails with its event, the polls before and after it store
    their samples whole."""
    got = _poll(tmp_path, _from_poll(10, "04"), lambda h: len(h.samples) >= 30,
                bus=FLAT_OUT, points=FAR)
    failed = [e for e in got.events if e.kind == "exception"]
    assert len(failed) == 1
    assert "address=300, count=1" in failed[0].message
    assert len(got.samples) >= 30
    assert _registers(got) == {tuple(WANT.values())}
    assert failed[0].monotonic > got.samples[8].monotonic


def _quiet_after(k: int) -> Script:
    """Right replies to the first ``k`` requests of a connection, then none."""
    def script(n: int, req: Request, conn: socket.socket) -> bytes | None:
        return good(*req) if n <= k else None
    return script


def test_a_device_polled_flat_out_that_falls_silent_times_out(tmp_path: Path) -> None:
    """Flat out and pipelined, a poll's three requests whole each time: the
    loop's C part carries the polls (sends each next one itself) until the
    device answers no more. The silent poll times out at its timeout (the
    sweep reads the C part's deadline as it nears), named as any timeout is;
    every poll answered before it is stored."""
    got = _poll(tmp_path, _quiet_after(150), lambda h: "timeout" in h.kinds(),
                bus="timeout = 0.3\ninterval = 0\npipeline = 4\n", points=FAR, within=10.0)
    timeouts = [e for e in got.events if e.kind == "timeout"]
    assert timeouts, got.kinds()
    assert "read_holding_registers(slave=1" in timeouts[0].message
    assert len(got.samples) == 50  # 150 requests, 3 a poll
    assert _registers(got) == {tuple(WANT.values())}
    late = timeouts[0].monotonic - got.samples[-1].monotonic
    assert 0.3 <= late < 1.5, late  # (its timeout, a sweep's tick and a loaded machine's slack)


def _silent_between(first: int, last: int) -> Script:
    """Right replies to a connection's requests but its ``first`` to ``last``."""
    def script(n: int, req: Request, conn: socket.socket) -> bytes | None:
        return None if first <= n <= last else good(*req)
    return script


def test_a_device_polled_flat_out_that_comes_back_says_so_once(tmp_path: Path) -> None:
    """Flat out and pipelined, the device leaves three polls unanswered
    (``offline_after = 3``: offline, tried again 0.5 s later) and then
    answers again: its first poll after that is carried by the loop's C
    part as the ones before the silence were, and says ``online`` once; the
    device's fault is cleared from the run's problems; later polls say
    nothing."""
    got = _poll(tmp_path, _silent_between(91, 99),
                lambda h: "online" in h.kinds() and len(h.samples) >= 60,
                bus="timeout = 0.3\ninterval = 0\npipeline = 4\n", points=FAR, within=15.0)
    assert [k for k in got.kinds() if k != "skipped"] == [
        "connect", "timeout", "timeout", "timeout", "online"], got.events
    back = got.events[-1].monotonic
    later = [s for b in got.blocks for s in b.samples() if s.monotonic >= back]
    assert later, "the polls after the silence were not the C part's"
    assert got.stats.device_faults["hx-1"] == 3
    assert got.stats.status == "ok"
    assert _registers(got) == {tuple(WANT.values())}


def _answered(nodelay: bool) -> Script:
    """Every request answered right, by a gateway whose socket keeps Nagle's
    algorithm on (a plain socket's default) or sets TCP_NODELAY."""
    def script(n: int, req: Request, conn: socket.socket) -> bytes:
        if n == 1 and nodelay:
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        return good(*req)
    return script


def test_a_gateway_with_nagles_algorithm_is_polled_faster_one_request_at_a_time(
        tmp_path: Path) -> None:
    """docs/gateway.md: a gateway that leaves Nagle's algorithm on holds a
    pipelined poll's replies after the first until the master's system
    acknowledges one, which Linux delays (tens of milliseconds); with
    ``pipeline = 1`` each request carries the acknowledgement of the reply
    before it. Flat out for the same time, 3-request polls: the advice
    holds (several times the polls), and TCP_NODELAY on the gateway is what
    makes the difference."""
    def polls(pipeline: int, nodelay: bool) -> int:
        gw = Hostile(_answered(nodelay))
        try:
            got = poll(tmp_path, [gw.port], lambda h: False, within=1.5, points=FAR,
                       bus=f"timeout = 0.5\ninterval = 0\npipeline = {pipeline}\n")
        finally:
            gw.close()
        assert {(u, r[:2]) for u, r in got.values()} <= {(1, (100, 101))}, got.events
        return len(got.samples)

    nagle_pipelined, nagle_one = polls(4, False), polls(1, False)
    nodelay_pipelined = polls(4, True)
    assert nagle_one > 3 * nagle_pipelined, (nagle_one, nagle_pipelined)
    assert nodelay_pipelined > 3 * nagle_pipelined, (nodelay_pipelined, nagle_pipelined)
