"""``pymb log`` on a device whose replies are not taken: one that answers
with another transaction id (it does not echo the request's, [MB-TCP]
3.1.3) is no silent device, and its timeout says so in the client's words;
a reply cut short says how far it came; a slow device's late reply to a
request the loop gave up on stays a skipped late reply. Real peers on
127.0.0.1 (scripted from the specification, not pymb's simulator), real
``pymb log`` runs from a config file as a user writes it."""

from __future__ import annotations

import socket
import sqlite3
import time
from pathlib import Path

import pytest
from conftest import run_pymb
from hostile_gateway import HX_MAP, Hostile, Request, Script, good, poll
from wire_peers import UdpPeer, udp_read_reply

import pymb

#: the client's words for a timeout after dropped replies to another id
FOREIGN = "what came was not the answer: reply to another transaction id (received "
#: the client's words for a silent device
SILENT = "(the device is silent, or the address, baud rate or wiring is wrong)"
#: a holding-register map whose poll is three requests (points at 0-1, 300, 600)
FAR = "".join(f'[[point]]\nname = "p{a}"\naddress = {a}\ntype = "u16"\n' for a in (300, 600))


def _other_tid(every: int = 1, tid: int = 0) -> Script:
    """Right replies, but for every ``every``-th request of all, answered
    (with its right registers) under transaction id ``tid``."""
    seen = [0]

    def script(n: int, req: Request, conn: socket.socket) -> bytes:
        seen[0] += 1
        reply = good(*req)
        return tid.to_bytes(2, "big") + reply[2:] if seen[0] % every == 0 else reply
    return script


def _log(tmp: Path, buses: str, seconds: float = 2.5) -> tuple[str, list[tuple[str, str, str]]]:
    """Run ``pymb log --config`` over ``buses`` (``[[bus]]`` tables of
    HX_MAP devices): its stderr and its events (device, kind, message)."""
    (tmp / "hx.toml").write_text(HX_MAP)
    (tmp / "log.toml").write_text('maps = ["hx.toml"]\n' + buses)
    db = tmp / "data.sqlite"
    r = run_pymb("log", "--config", str(tmp / "log.toml"), "--seconds", str(seconds),
                 "--out", str(db), "--quiet", timeout=60)
    assert "Traceback" not in r.stderr, r.stderr
    con = sqlite3.connect(db)
    try:
        events = con.execute("SELECT d.name, e.kind, e.message FROM events e JOIN devices d "
                             "ON d.id = e.device_id ORDER BY e.id").fetchall()
    finally:
        con.close()
    return r.stderr, events


def _bus(name: str, kind: str, where: str) -> str:
    return (f'[[bus]]\nname = "{name}"\n{kind} = "{where}"\ntimeout = 0.2\ninterval = 0.05\n'
            f'[[bus.device]]\ntype = "hx"\nname = "{name}"\naddress = 3\n')


def test_pymb_log_names_a_device_that_answers_another_transaction_id(tmp_path: Path) -> None:
    """One device answers every request under transaction id 0, one every
    third: ``pymb log``'s events and its closing summary say what a
    TcpClient says of the same device (the reply it dropped, shown), not
    that the device is silent; the second device's good replies are stored."""
    wrong = Hostile(_other_tid())
    sometimes = Hostile(_other_tid(3))
    try:
        err, events = _log(tmp_path, _bus("wrong", "tcp", f"127.0.0.1:{wrong.port}")
                           + _bus("sometimes", "tcp", f"127.0.0.1:{sometimes.port}"))
        with (pymb.TcpClient("127.0.0.1", wrong.port, slave=3, timeout=0.2) as c,
              pytest.raises(pymb.ModbusTimeout) as said):
            c.read_holding_registers(0, 2)
    finally:
        wrong.close()
        sometimes.close()
    client = str(said.value)
    assert FOREIGN + "00 00 00 00 00 07 03 03 04 01 2C 01 2D)" in client, client
    timeouts = {d: [m for dd, k, m in events if dd == d and k == "timeout"]
                for d in ("wrong", "sometimes")}
    assert timeouts["wrong"], events
    assert timeouts["sometimes"], events
    assert timeouts["wrong"][0] == client, (timeouts["wrong"][0], client)
    for m in timeouts["wrong"] + timeouts["sometimes"]:
        assert FOREIGN in m, m
        assert SILENT not in m, m
    # the summary's line: the client's words, as a protocol fault's are
    assert f"pymb log: wrong delivered no sample: {client}\n" in err, err
    assert "sometimes delivered no sample" not in err, err


@pytest.mark.parametrize("flat_out", [False, True], ids=["interval", "flat-out"])
def test_a_pipelined_poll_names_the_request_answered_under_another_id(
        tmp_path: Path, flat_out: bool) -> None:
    """A poll of three requests in flight at once, every fifth reply under
    another id: the loop's timeout (and, flat out, the C loop's carried
    polls) names the dropped reply; the other polls are stored whole."""
    gw = Hostile(_other_tid(5, tid=0x7F7F))
    try:
        got = poll(tmp_path, [gw.port], lambda h: h.kinds().count("timeout") >= 2
                   and len(h.samples) >= 5, points=FAR,
                   bus=f"timeout = 0.3\ninterval = {0 if flat_out else 0.05}\npipeline = 4\n")
    finally:
        gw.close()
    timeouts = [e.message for e in got.events if e.kind == "timeout"]
    assert len(timeouts) >= 2, got.events
    for m in timeouts:
        assert FOREIGN + "7F 7F 00 00 00 " in m, m
        assert SILENT not in m, m
    for s in got.samples:
        regs = s.data.registers  # type: ignore[union-attr]
        assert {a: regs[a] for a in (0, 1, 300, 600)} == {0: 100, 1: 101, 300: 400, 600: 700}


def _slow_first(k: int, delay: float) -> Script:
    """The first ``k`` requests of all answered right after ``delay``
    seconds (the script holds the connection meanwhile), the rest at once."""
    seen = [0]

    def script(n: int, req: Request, conn: socket.socket) -> bytes:
        seen[0] += 1
        if seen[0] <= k:
            time.sleep(delay)
        return good(*req)
    return script


def test_a_late_reply_to_a_request_given_up_on_stays_a_skipped_late_one(tmp_path: Path) -> None:
    """A slow device: the first two polls time out (0.2 s) and their
    replies come 0.3 s after each request, in the next poll's wait. Each is
    a late reply to a request the loop gave up on, skipped: the second
    timeout (whose wait saw the first's late reply) is a plain one, not
    blamed on a reply to another transaction id; the third poll is stored."""
    gw = Hostile(_slow_first(2, 0.3))
    try:
        got = poll(tmp_path, [gw.port], lambda h: len(h.samples) >= 3)
    finally:
        gw.close()
    timeouts = [e.message for e in got.events if e.kind == "timeout"]
    assert len(timeouts) == 2, got.events
    for m in timeouts:
        assert m.endswith("no reply within the 0.2 s timeout " + SILENT), m
    assert got.values() == {(1, (100, 101))}


def test_a_reply_cut_short_reads_as_a_clients_timeout(tmp_path: Path) -> None:
    """A device whose replies stop after 5 bytes: the loop's timeout says
    how far the reply came, as a client's does of the same request."""
    gw = Hostile(lambda n, req, conn: good(*req)[:5])
    try:
        got = poll(tmp_path, [gw.port], lambda h: "timeout" in h.kinds())
        with (pymb.TcpClient("127.0.0.1", gw.port, slave=1, timeout=0.2) as c,
              pytest.raises(pymb.ModbusTimeout) as said):
            c.read_holding_registers(0, 2)
    finally:
        gw.close()
    client = str(said.value)
    assert "the reply was incomplete after 5 bytes, within the 0.2 s timeout" in client, client
    timeouts = [e.message for e in got.events if e.kind == "timeout"]
    assert timeouts[0] == client, (timeouts[0], client)
    # the status line's and the summary's words: the whole text, not "no reply"
    assert got.stats.last_fault["hx-1"] == f"hx-1: {client}"


def test_pymb_log_over_udp_names_a_reply_to_another_transaction_id(tmp_path: Path) -> None:
    """A UDP device (polled by a UdpClient of its bus) answering under
    another transaction id: the same words in the events and the summary."""
    with UdpPeer(lambda i, req: [(0, udp_read_reply(req, [9, 9], tid=0))]) as peer:
        err, events = _log(tmp_path, _bus("udp", "udp", f"127.0.0.1:{peer.port}"), 1.5)
    timeouts = [m for d, k, m in events if k == "timeout"]
    assert timeouts, events
    for m in timeouts:
        assert FOREIGN + "00 00 " in m, m
        assert SILENT not in m, m
    assert f"pymb log: udp delivered no sample: {timeouts[0]}\n" in err, err
