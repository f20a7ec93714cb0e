"""``pymb scan``: which addresses answer on a bus, and which device each is.

On a serial line the scan does not wait for each address in turn. It sends
one short question to each address (FC 0x04, registers 100..107: a CoolPro
answers with its identity, a hub with exception 01, any Modbus device with
something) and listens to the line the whole time. An RTU reply names the
address that sent it, so a reply that comes late, while a later address is
being asked, is credited to its sender, never to the address being asked.
Every address heard from is then confirmed with a slower probe (long enough
for the hub's documented 500 ms) and identified; only what confirms is
listed, so a garbled or stray frame never becomes a phantom device. Each
device is printed (and flushed) as soon as it is confirmed.

Through a TCP gateway (which matches replies to requests itself) each
address is identified in turn with ``--timeout``; a gateway's exception
0x0A or 0x0B (no path to the address, no answer from it) counts as
silence. A gateway in front of a serial line answers one request at a time
and waits its own timeout for an address that is silent: give ``--timeout``
above the gateway's (``pymb serve``'s ``--timeout``, 1 s by default).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import queue
import signal
import struct
import sys
import threading
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from types import FrameType
from typing import cast

from pymb.client import Client, RtuClient
from pymb.client.listener import LineListener
from pymb.commands._common import add_connection_args, add_map_arg, make_client, parse_numbers
from pymb.devices.coolpro import IDENTITY_REQUEST
from pymb.devices.identify import Answer, Identity, client_asker, identify
from pymb.devices.mapspec import map_types, match_map
from pymb.errors import InvalidArgument
from pymb.maps import Map
from pymb.wire import bits_per_char

__all__ = ["LineListener", "add_arguments", "line_asker", "parse_range", "run"]



def add_arguments(p: argparse.ArgumentParser) -> None:
    """Arguments of ``pymb scan``."""
    add_connection_args(p, timeout=0.05)
    p.add_argument("--range", default="1-255", metavar="A-B[,C...]",
                   help="addresses to try (default 1-255: the hub uses up to 255)")
    p.add_argument("--confirm-timeout", type=float, metavar="S",
                   help="seconds to wait for a device being confirmed, at most 60 (default: "
                        "the hub's documented 0.5 s plus the reply's wire time, or --timeout "
                        "if longer)")
    p.add_argument("--json", action="store_true", help="print JSON")
    add_map_arg(p)


def parse_range(spec: str) -> list[int]:
    """``1-10,40,248-255`` -> the addresses, in order, without repeats."""
    return parse_numbers(spec, 1, 255, f"--range {spec!r}: use e.g. 1-247 or 1-10,40,250")


@dataclass
class Found:
    """One address that answered and confirmed."""

    address: int
    device: str  #: coolpro, hub, a map's id, or "unknown"
    detail: str


def line_asker(line: LineListener, timeout: float) -> Callable[[int, int, bytes], Answer]:
    """``ask`` for :func:`~pymb.devices.identify.identify`, over a listened line."""

    def ask(address: int, function: int, data: bytes) -> Answer:
        for _ in range(2):  # a lost reply is asked again once: noise is no answer
            sent = line.send(address, function, data)
            frame = line.listen(sent + timeout, address, function)
            if frame is not None:
                return frame[2] if frame[1] & 0x80 else frame[2:-2]
        return None

    return ask


#: [HUB] 2.1: the hub answers within 500 ms (the slowest device pymb knows)
_HUB_ANSWER_S = 0.5
_CONFIRM_MAX_S = 60.0  #: the longest a device being confirmed is waited for


def _probe() -> tuple[int, bytes]:
    fc, first, count = IDENTITY_REQUEST
    return fc, struct.pack(">HH", first, count)


def scan_rtu(client: RtuClient, addresses: list[int], timeout: float,
             confirm_timeout: float, known: Mapping[str, Map] | None = None
             ) -> Iterator[tuple[str, object]]:
    """Yields ("progress", (address, index)), ("found", Found) and
    ("unconfirmed", address) as the scan goes."""
    line = LineListener(client.fileno(), client.baudrate,
                        bits_per_char(client.parity, client.stop_bits, client.data_bits))
    ask = line_asker(line, confirm_timeout)
    done: set[int] = set()
    fc, data = _probe()

    def confirm() -> Iterator[tuple[str, object]]:
        while line.heard:
            m = line.heard.pop(0)
            if m in done:
                continue
            done.add(m)
            ident = identify(ask, m)
            if ident is None:
                yield "unconfirmed", m
            else:
                yield "found", _found(ident, ask, known)

    asked: set[int] = set()
    for i, a in enumerate(addresses, 1):
        yield "progress", (a, i)
        if a in done:
            continue
        asked.add(a)
        heard = len(line.heard)
        sent = line.send(a, fc, data)
        if line.listen(sent + timeout, a, fc) is not None:
            line.heard.insert(0, a)
        elif any(m not in asked for m in line.heard[heard:]):
            # A reply from an address not asked yet is no late reply: it may be
            # the answer to this question, mangled. Ask this address again too.
            line.heard.append(a)
        yield from confirm()
    # Late replies to the last questions: the hub may take 500 ms.
    line.listen(time.monotonic() + confirm_timeout)
    yield from confirm()


def scan_client(client: Client, addresses: list[int],
                known: Mapping[str, Map] | None = None) -> Iterator[tuple[str, object]]:
    """Each address in turn, through the client (TCP gateways)."""
    ask = client_asker(client)
    for i, a in enumerate(addresses, 1):
        yield "progress", (a, i)
        ident = identify(ask, a)
        if ident is not None:
            yield "found", _found(ident, ask, known)


def _found(ident: Identity, ask: Callable[[int, int, bytes], Answer],
           known: Mapping[str, Map] | None) -> Found:
    """What answered: a device a map recognises (its ``[[identify]]`` rules
    all hold), else what :func:`identify` made of it."""
    matched = match_map(ask, ident.address, known) if known else None
    if matched is not None:
        return Found(ident.address, *matched)
    return Found(ident.address, ident.device, ident.detail)


def run(args: argparse.Namespace) -> int:
    """Try every address in the range; print what answered as it is confirmed."""
    addresses = parse_range(args.range)
    known = map_types(args.maps)
    client = make_client(args)
    confirm_timeout = args.confirm_timeout
    if confirm_timeout is None:
        baud = getattr(client, "baudrate", 9600)
        confirm_timeout = min(_CONFIRM_MAX_S,
                              max(args.timeout, _HUB_ANSWER_S + 0.15 + 60 * 11 / baud))
    if not 0 < confirm_timeout <= _CONFIRM_MAX_S:
        raise InvalidArgument(f"--confirm-timeout must be more than 0 and at most "
                              f"{_CONFIRM_MAX_S:g} s, got {confirm_timeout:g}")
    # A SimpleQueue (C, reentrant): the main thread waits in no Python-level
    # lock code, and Ctrl-C comes as an event (see _ctrl_c_as_event).
    events: queue.SimpleQueue[tuple[str, object]] = queue.SimpleQueue()

    def work() -> None:
        try:
            with client:
                steps = (scan_rtu(client, addresses, args.timeout, confirm_timeout, known)
                         if isinstance(client, RtuClient) else
                         scan_client(client, addresses, known))
                for step in steps:
                    events.put(step)
        except BaseException as e:  # handed to the main thread
            events.put(("fatal", e))
        events.put(("end", None))

    found: list[Found] = []
    unconfirmed: list[int] = []
    tty = sys.stderr.isatty()
    t0 = time.monotonic()
    interrupted = False
    try:
        with _ctrl_c_as_event(events):
            threading.Thread(target=work, name="pymb-scan", daemon=True).start()
            while True:
                kind, item = events.get()
                if kind == "end":
                    break
                if kind == "interrupt":
                    raise KeyboardInterrupt
                if kind == "fatal":
                    assert isinstance(item, BaseException)
                    raise item
                if kind == "progress" and tty:
                    where, index = cast(tuple[int, int], item)
                    sys.stderr.write(f"\r\x1b[Kscanning {where} ({index}/{len(addresses)}), "
                                     f"{len(found)} found")
                    sys.stderr.flush()
                elif kind == "unconfirmed":
                    unconfirmed.append(int(item))  # type: ignore[call-overload]
                elif kind == "found":
                    assert isinstance(item, Found)
                    found.append(item)
                    if tty:
                        sys.stderr.write("\r\x1b[K")
                        sys.stderr.flush()
                    if not args.json:
                        print(f"{item.address:3d}  {item.device:8s} {item.detail}", flush=True)
    except KeyboardInterrupt:
        interrupted = True
    if tty:
        sys.stderr.write("\r\x1b[K")
    elapsed = time.monotonic() - t0
    if args.json:
        doc = {"port": client.port, "scanned": len(addresses), "seconds": elapsed,
               "found": [f.__dict__ for f in sorted(found, key=lambda f: f.address)]}
        if interrupted:
            doc["interrupted"] = True
        sys.stdout.write(json.dumps(doc, indent=2) + "\n")
        sys.stdout.flush()
    note = (f"; {len(unconfirmed)} address(es) heard once but silent when asked again: "
            f"{', '.join(map(str, unconfirmed))}" if unconfirmed else "")
    print(f"{len(found)} device(s) in {len(addresses)} addresses, {elapsed:.1f} s"
          + (" (interrupted)" if interrupted else "") + note, file=sys.stderr)
    if interrupted:
        raise KeyboardInterrupt
    return 0


@contextlib.contextmanager
def _ctrl_c_as_event(events: queue.SimpleQueue[tuple[str, object]]) -> Iterator[None]:
    """While the scan runs, Ctrl-C (SIGINT) puts ("interrupt", None) on
    ``events`` instead of raising KeyboardInterrupt wherever the main thread
    is: raised between a lock's wait and its re-acquire (``threading``'s
    Condition, under ``queue.Queue.get`` or ``Thread.start``), it left the
    lock released and its ``with`` ended in ``RuntimeError: release unlocked
    lock``, a traceback. ``SimpleQueue.put`` may be called from a signal
    handler. Outside the main thread (no handler can be set) as before."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def on_sigint(signum: int, frame: FrameType | None) -> None:
        events.put(("interrupt", None))

    previous = signal.signal(signal.SIGINT, on_sigint)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
