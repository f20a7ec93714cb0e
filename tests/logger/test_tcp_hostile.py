"""The one TCP loop (:mod:`pymb.logger.tcploop`) against hostile gateways
(:mod:`hostile_gateway`): whatever a gateway does, the loop keeps going,
stores only the registers of the right request of the right unit, counts
the fault against the device, records it as an event and recovers."""

from __future__ import annotations

import socket
import sqlite3
import struct
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from conftest import run_pymb
from hostile_gateway import HX_MAP, Handed, Hostile, Request, Script, good, poll
from peerkit import mbap, registers

import pymb


def test_a_gateway_that_drops_every_connection_is_retried_with_the_backoff(
        tmp_path: Path) -> None:
    """Accepted, then closed at once, every time: the bus is opened again
    after 0.5 s, then 1 s (as a refused connection is), not at once in a
    loop that fills the log with events."""
    gw = Hostile(None)
    try:
        got = poll(tmp_path, [gw.port], lambda h: h.kinds().count("connection") >= 3)
    finally:
        gw.close()
    assert len(gw.accepted) >= 3
    assert gw.accepted[2] - gw.accepted[0] >= 1.4, gw.accepted
    assert got.samples == []
    # an event per connection lost, each told to the device it was polling
    lost = [e for e in got.events if e.kind == "connection"]
    assert len(lost) == len(gw.accepted) == 3
    assert all(e.device is not None and e.device.address == 1 for e in lost), lost
    assert got.stats.device_faults["hx-1"] == len(lost)


def _once(lie: Callable[[bytes], bytes], at: int = 3) -> Script:
    """A script answering right but for the ``at``-th request of all,
    whose reply is ``lie(right reply)``."""
    seen = [0]

    def script(n: int, req: Request, conn: socket.socket) -> bytes:
        seen[0] += 1
        reply = good(*req)
        return lie(reply) if seen[0] == at else reply
    return script


def test_a_reply_whose_length_lies_costs_one_timeout(tmp_path: Path) -> None:
    """A reply whose length field promises more than comes: one timeout,
    then a new connection (the bytes left over would be read as the start
    of the next replies, which would time out one after the other)."""
    gw = Hostile(_once(lambda r: r[:4] + b"\x00\x40" + r[6:]))
    try:
        got = poll(tmp_path, [gw.port], lambda h: len(h.samples) >= 12)
    finally:
        gw.close()
    assert got.kinds().count("timeout") == 1, got.events
    assert "reconnect" in got.kinds()
    assert len(got.samples) >= 12
    assert got.values() == {(1, (100, 101))}


def test_a_name_lookup_that_hangs_does_not_stop_the_other_buses(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The resolver takes its time over one bus's host name (a board whose
    DNS server is gone waits seconds per lookup): the other buses are polled
    meanwhile, and the name that does not resolve is one event line."""
    release = threading.Event()
    blocked = threading.Event()
    real = socket.getaddrinfo

    def slow(host: Any, *args: Any, **kwargs: Any) -> Any:
        if host == "slow.invalid":
            blocked.set()
            release.wait(10.0)
            raise socket.gaierror(socket.EAI_NONAME, "Name or service not known")
        return real(host, *args, **kwargs)

    monkeypatch.setattr(socket, "getaddrinfo", slow)
    gw = Hostile(lambda n, req, conn: good(*req))
    meanwhile: list[int] = []

    def until(h: Handed) -> bool:
        if not release.is_set() and blocked.is_set() and len(h.samples) >= 10:
            meanwhile.append(len(h.samples))  # read while the lookup hung
            release.set()
        return release.is_set() and "connection" in h.kinds()

    try:
        got = poll(tmp_path, ["slow.invalid:502", gw.port], until)
    finally:
        release.set()
        gw.close()
    assert meanwhile, "no samples while a lookup hung"
    lost = [e for e in got.events if e.kind == "connection"]
    assert lost[0].bus == "bus1"
    assert lost[0].message.startswith("the host name 'slow.invalid' did not resolve"), lost
    assert "\n" not in lost[0].message
    assert got.values() == {(1, (100, 101))}


def _exception(code: int) -> Callable[[bytes], bytes]:
    return lambda r: r[:4] + b"\x00\x03" + r[6:7] + bytes((r[7] | 0x80, code))


#: (what the gateway does to the 3rd reply of all, the event it makes)
LIES: dict[str, tuple[Callable[[bytes], bytes], str]] = {
    "another transaction id": (lambda r: b"\x7f\x7f" + r[2:], "timeout"),
    "protocol id 1": (lambda r: r[:3] + b"\x01" + r[4:], "protocol"),
    "length 3": (lambda r: r[:4] + b"\x00\x03" + r[6:], "protocol"),
    "length 0": (lambda r: r[:4] + b"\x00\x00" + r[6:], "protocol"),
    "length 65535": (lambda r: r[:4] + b"\xff\xff" + r[6:], "protocol"),
    "another unit": (lambda r: r[:6] + b"\x09" + r[7:], "protocol"),
    "another function": (lambda r: r[:7] + b"\x04" + r[8:], "protocol"),
    "byte count 2": (lambda r: r[:4] + b"\x00\x05" + r[6:8] + b"\x02" + r[9:11], "protocol"),
    "exception 0B": (_exception(0x0B), "exception"),
    "exception 0A": (_exception(0x0A), "exception"),
    "exception 04": (_exception(0x04), "exception"),
    "garbage first": (lambda r: b"\x13\x37\x00" + r, "protocol"),
    "a reply never asked for first": (lambda r: b"\x7f\x7f" + r[2:] + r, ""),
    "twice, glued": (lambda r: r + r, ""),
}


@pytest.mark.parametrize("lie", list(LIES))
def test_a_reply_that_lies_is_counted_and_never_stored(tmp_path: Path, lie: str) -> None:
    """The 3rd reply of the gateway lies: the poll fails with an event of
    the right kind against the device (counted), or the lie is skipped; no
    sample holds registers but the ones asked for; the polls go on."""
    how, kind = LIES[lie]
    gw = Hostile(_once(how))
    try:
        got = poll(tmp_path, [gw.port], lambda h: len(h.samples) >= 8)
    finally:
        gw.close()
    faults = [e for e in got.events if e.kind not in ("connect", "reconnect", "skipped")]
    assert [e.kind for e in faults] == ([kind] if kind else []), faults
    assert all(e.device is not None and e.device.address == 1 for e in faults)
    assert got.stats.device_faults.get("hx-1", 0) == len(faults)
    assert len(got.samples) >= 8
    assert got.values() == {(1, (100, 101))}


def _dribble(n: int, req: Request, conn: socket.socket) -> None:
    for b in good(*req):
        conn.send(bytes((b,)))
        time.sleep(0.002)


def _reset_mid_reply(n: int, req: Request, conn: socket.socket) -> bytes | None:
    if n == 3:
        conn.sendall(good(*req)[:7])
        time.sleep(0.05)
        conn.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        conn.close()  # an RST
        return None
    return good(*req)


@pytest.mark.parametrize(("script", "kinds"), [
    (_dribble, []),
    (_reset_mid_reply, ["connection", "reconnect"]),
])
def test_a_reply_in_pieces_or_cut_by_a_reset(tmp_path: Path, script: Script,
                                             kinds: list[str]) -> None:
    """A reply written a byte at a time is read whole; one cut by a reset is
    a ``connection`` event for the device, and the bus is opened again."""
    gw = Hostile(script)
    try:
        got = poll(tmp_path, [gw.port], lambda h: len(h.samples) >= 8,
                   bus="timeout = 0.5\ninterval = 0.05\n")
    finally:
        gw.close()
    assert [k for k in got.kinds() if k not in ("connect", "skipped")][:2] == kinds
    assert got.values() == {(1, (100, 101))}


def _chatter() -> Script:
    """Right replies; after the 3rd of all, bytes no request asked for."""
    seen = [0]

    def script(n: int, req: Request, conn: socket.socket) -> None:
        seen[0] += 1
        conn.sendall(good(*req))
        if seen[0] == 3:
            time.sleep(0.01)  # (the next poll is 0.05 s away)
            conn.sendall(b"\x00\x01\x00\x01\x00\x03\x01\x83\x02")
    return script


def test_bytes_between_polls_are_an_event(tmp_path: Path) -> None:
    """Bytes that are no Modbus TCP reply, sent when no request is out,
    close the connection with a ``protocol`` event (it was closed without a
    word); the bus is opened again and polled."""
    gw = Hostile(_chatter())
    try:
        got = poll(tmp_path, [gw.port],
                   lambda h: len(h.samples) >= 8 and "reconnect" in h.kinds())
    finally:
        gw.close()
    odd = [e for e in got.events if e.kind == "protocol"]
    assert len(odd) == 1, got.events
    assert "00 01 00 01 00 03 01 83 02" in odd[0].message
    assert got.values() == {(1, (100, 101))}


def test_refused_then_accepted(tmp_path: Path) -> None:
    """Nobody listens at first: ``connection`` events that say the backoff
    (0.5 s, then 1 s); once a gateway listens, the bus connects and polls."""
    with socket.create_server(("127.0.0.1", 0)) as s:
        port = s.getsockname()[1]
    gws: list[Hostile] = []

    def until(h: Handed) -> bool:
        if not gws and h.kinds().count("connection") >= 2:
            gws.append(Hostile(lambda n, req, conn: good(*req), port))
        return len(h.samples) >= 5

    try:
        got = poll(tmp_path, [port], until)
    finally:
        for gw in gws:
            gw.close()
    refused = [e.message for e in got.events if e.kind == "connection"]
    assert "Connection refused; retrying in 0.5 s" in refused[0], refused
    assert "retrying in 1 s" in refused[1], refused
    assert got.kinds()[len(refused)] == "connect"
    assert got.values() == {(1, (100, 101))}


#: two more points, too far apart to be read in one request: a poll of 3
FAR = "".join(f'[[point]]\nname = "p{a}"\naddress = {a}\ntype = "u16"\n' for a in (300, 600))


def _backwards() -> Script:
    """Each poll's 3 requests answered together, the last first."""
    held: dict[int, list[Request]] = {}

    def script(n: int, req: Request, conn: socket.socket) -> bytes | None:
        mine = held.setdefault(id(conn), [])
        mine.append(req)
        if len(mine) < 3:
            return None
        out = b"".join(good(*r) for r in reversed(mine))
        mine.clear()
        return out
    return script


def test_pipelined_replies_in_any_order(tmp_path: Path) -> None:
    """With ``pipeline = 4`` a gateway answers a poll's three requests last
    first (a server may: the transaction id tells them apart): each reply
    goes to its own request's place, every poll makes its sample."""
    gw = Hostile(_backwards())
    try:
        got = poll(tmp_path, [gw.port], lambda h: len(h.samples) >= 10, units=(1, 2),
                   bus="timeout = 0.5\ninterval = 0.05\npipeline = 4\n", points=FAR)
    finally:
        gw.close()
    assert [k for k in got.kinds() if k not in ("connect", "skipped")] == []
    want = {u: {0: 100 * u, 1: 100 * u + 1, 300: 100 * u + 300, 600: 100 * u + 600}
            for u in (1, 2)}
    for s in got.samples:
        regs = s.data.registers  # type: ignore[union-attr]
        assert {a: regs[a] for a in (0, 1, 300, 600)} == want[s.device.address]
    assert {s.device.address for s in got.samples} == {1, 2}


def test_pymb_log_beside_hostile_gateways(tmp_path: Path) -> None:
    """A real ``pymb log`` run: one gateway answers right, one drops every
    connection, one lies about the protocol id in every 4th reply. The run
    ends as it should (exit 3, one line for the device that never
    delivered); the good bus's samples, and the liar's, hold their own
    registers; the faults are events in the file, the dropper's a few
    (backoff), not one per sweep."""
    (tmp_path / "hx.toml").write_text(HX_MAP)
    right = Hostile(lambda n, req, conn: good(*req))
    dropper = Hostile(None)
    liar = Hostile(lambda n, req, conn: good(*req)[:3] + b"\x01" + good(*req)[4:]
                   if n % 4 == 0 else good(*req))
    text = 'maps = ["hx.toml"]\n'
    for name, gw in (("right", right), ("dropper", dropper), ("liar", liar)):
        text += (f'[[bus]]\nname = "{name}"\ntcp = "127.0.0.1:{gw.port}"\ntimeout = 0.2\n'
                 f'interval = 0.05\n[[bus.device]]\ntype = "hx"\nname = "{name}"\n'
                 'address = 3\n')
    (tmp_path / "log.toml").write_text(text)
    db = tmp_path / "data.sqlite"
    try:
        r = run_pymb("log", "--config", str(tmp_path / "log.toml"), "--seconds", "3",
                     "--out", str(db), "--quiet", timeout=60)
    finally:
        for gw in (right, dropper, liar):
            gw.close()
    assert r.returncode == 3, r.stderr  # a device delivered nothing
    assert "Traceback" not in r.stderr
    assert "pymb log: dropper delivered no sample: " in r.stderr
    con = sqlite3.connect(db)
    try:
        regs = con.execute("SELECT d.name, s.registers, count(*) FROM samples s JOIN devices d"
                           " ON d.id = s.device_id GROUP BY d.name, s.registers").fetchall()
        events = con.execute("SELECT bus, kind FROM events").fetchall()
    finally:
        con.close()
    assert {(name, bytes(blob)) for name, blob, _ in regs} == {
        ("right", struct.pack(">2H", 300, 301)), ("liar", struct.pack(">2H", 300, 301))}
    counts = {name: n for name, _, n in regs}
    assert counts["right"] >= 20, counts
    assert counts["liar"] >= 10, counts
    assert ("liar", "protocol") in events
    dropped = [k for b, k in events if b == "dropper" and k == "connection"]
    assert 1 <= len(dropped) <= 4, events


def _ahead() -> Script:
    """Right replies; the 5th of all followed at once by a reply for the
    next transaction id (registers 999), before that request is sent."""
    seen = [0]

    def script(n: int, req: Request, conn: socket.socket) -> bytes:
        seen[0] += 1
        out = good(*req)
        if seen[0] == 5:
            tid, unit, fc, _, _ = req
            out += mbap((tid + 1) & 0xFFFF, unit, bytes((fc,)) + registers([999, 999]))
        return out
    return script


def test_a_reply_that_comes_before_its_request_is_skipped(tmp_path: Path) -> None:
    """Polled flat out, the next request goes out as soon as a reply is in:
    a reply glued behind it for the transaction id that request will have
    came before the request and answers nothing (stored, it would put a
    server's guess into the log)."""
    gw = Hostile(_ahead())
    try:
        got = poll(tmp_path, [gw.port], lambda h: len(h.samples) >= 30,
                   bus="timeout = 0.5\ninterval = 0\n")
    finally:
        gw.close()
    assert got.values() == {(1, (100, 101))}
    assert got.kinds() == ["connect"]


def _silent_first(k: int) -> Script:
    """No answer to the first ``k`` requests of all, then right ones."""
    seen = [0]

    def script(n: int, req: Request, conn: socket.socket) -> bytes | None:
        seen[0] += 1
        return good(*req) if seen[0] > k else None
    return script


def test_a_unit_silent_for_a_while_goes_offline_and_comes_back(tmp_path: Path) -> None:
    """Three timeouts in a row (``offline_after = 3``) take the unit offline
    (said once, with the retry); a poll ``offline_retry`` later finds it
    again: an ``online`` event, and samples; the faults are counted."""
    gw = Hostile(_silent_first(3))
    try:
        got = poll(tmp_path, [gw.port], lambda h: len(h.samples) >= 5)
    finally:
        gw.close()
    kinds = [k for k in got.kinds() if k != "skipped"]
    assert kinds == ["connect", "timeout", "timeout", "timeout", "online"], got.events
    timeouts = [e.message for e in got.events if e.kind == "timeout"]
    assert "offline after 3 failed poll(s), next try in 0.5 s" in timeouts[2]
    assert not any("offline" in m for m in timeouts[:2])
    assert got.stats.device_faults["hx-1"] == 3
    assert got.values() == {(1, (100, 101))}


@pytest.mark.parametrize("how", ["exception 04", "silent"])
def test_a_failed_request_reads_as_a_clients_error(tmp_path: Path, how: str) -> None:
    """The loop's event of a refused or unanswered request says what a
    client's error says of the same request to the same gateway: one text."""
    def script(n: int, req: Request, conn: socket.socket) -> bytes | None:
        return _exception(4)(good(*req)) if how != "silent" else None

    gw = Hostile(script)
    try:
        got = poll(tmp_path, [gw.port], lambda h: len(h.events) >= 2)
        with (pymb.TcpClient("127.0.0.1", gw.port, timeout=0.2) as c,
              pytest.raises(pymb.ModbusError) as said):
            c.read_holding_registers(0, 2, slave=1)
    finally:
        gw.close()
    faults = [e for e in got.events if e.kind not in ("connect", "reconnect")]
    assert faults, got.events
    assert faults[0].message == str(said.value), (faults[0].message, str(said.value))


def _silent_then_closed(n: int, req: Request, conn: socket.socket) -> None:
    """No answer on any connection; the 3rd request closes it (a gateway
    that gives up on a connection whose device is silent)."""
    if n == 3:
        conn.shutdown(socket.SHUT_RDWR)
        raise OSError("closed")


def test_a_silent_gateway_that_closes_the_connection_answered_nothing(tmp_path: Path) -> None:
    """Two requests time out, the gateway closes the connection on the
    3rd: that is a lost connection (an event for the device, the bus opened
    again after the backoff), not a device that closes its connection after
    two replies, and no limit of requests per connection is learned."""
    gw = Hostile(_silent_then_closed)
    try:
        got = poll(tmp_path, [gw.port], lambda h: h.kinds().count("connection") >= 2,
                   within=15.0)
    finally:
        gw.close()
    said = " ".join(e.message for e in got.events)
    assert "closed by the device after" not in said, got.events
    assert "per connection" not in said, got.events
    lost = [e for e in got.events if e.kind == "connection"]
    assert all(e.device is not None and e.device.address == 1 for e in lost), lost
    assert "the connection was closed by the device" in lost[0].message, lost
    assert gw.accepted[1] - gw.accepted[0] >= 0.9, gw.accepted  # two timeouts, the backoff
    assert got.samples == []
