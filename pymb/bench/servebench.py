"""``pymb bench --sections serve``: what ``pymb serve`` adds to a request.

Simulated CoolPros on pseudo-terminals (no wire emulation, the reply gap
0: pure software cost; one a way, as a line has one master) are read three
ways, turn about, the same telemetry
read (input registers 0..7) each time:

- **direct**: pymb's own RTU client on the line;
- **through serve**: ``pymb serve`` in front of the line, read by a plain
  socket client (Modbus TCP written by hand: no client library's cost), on a
  kept connection; then the same over TLS (Modbus/TCP Security, TLS 1.3, a
  client certificate).

Reported: each way's latency p50 and p99, what serve adds (p99 through
serve minus p99 direct; goal at most 1 ms), and ``pymb serve``'s own CPU per
read, plain and TLS, from ``/proc`` (every thread's schedstat, in
nanoseconds: CPU time, not wall time, as the machine may be busy). Plain and
TLS take turns, each round's pair under the same load; the TLS / plain figure
(goal at most 1.2) is the median of the rounds' ratios.
"""

from __future__ import annotations

import os
import re
import socket
import ssl
import statistics
import struct
import sys
import tempfile
import threading
import time
from typing import Any

from pymb.bench.cpuload import process_cpu
from pymb.bench.procs import Child, Children
from pymb.bench.table import Table, fmt_time, fmt_x, percentile
from pymb.child import pymb_argv

__all__ = ["run_section", "tables", "targets"]

_READ = struct.pack(">BHH", 4, 0, 8)  # CoolPro telemetry: input registers 0..7


def _cpu(pid: int) -> float:
    """Seconds of CPU process ``pid`` has used, every thread's, to the
    nanosecond where the kernel keeps schedstat (clock ticks otherwise)."""
    total, seen = 0, False
    for task in os.listdir(f"/proc/{pid}/task"):
        try:
            with open(f"/proc/{pid}/task/{task}/schedstat", encoding="ascii") as f:
                total += int(f.read().split()[0])
            seen = True
        except (OSError, ValueError, IndexError):
            continue  # a thread that ended in between, or no schedstat
    return total / 1e9 if seen else process_cpu(pid)


def _ask(sock: socket.socket | ssl.SSLSocket, tid: int) -> None:
    sock.sendall(struct.pack(">HHHB", tid, 0, len(_READ) + 1, 40) + _READ)
    want, buf = 6, b""
    while len(buf) < want:
        chunk = sock.recv(want - len(buf))
        if not chunk:
            raise ConnectionError("pymb serve closed the connection")
        buf += chunk
        if want == 6 and len(buf) == 6:
            want += struct.unpack(">H", buf[4:6])[0]
    if buf[7] != 4:
        raise RuntimeError(f"pymb serve answered {buf.hex(' ')}")


def _through(sock: socket.socket | ssl.SSLSocket, n: int) -> list[float]:
    out = []
    for i in range(n):
        t = time.perf_counter()
        _ask(sock, i & 0xFFFF)
        out.append(time.perf_counter() - t)
    return out


def _direct(port: str, n: int) -> list[float]:
    from pymb.client import RtuClient
    out = []
    with RtuClient(port, 115200, timeout=2.0) as c:
        for _ in range(n):
            t = time.perf_counter()
            c.read_input_registers(0, 8, slave=40)
            out.append(time.perf_counter() - t)
    return out


FAR_DELAY = 0.002  #: the far device's latency (s)
CLIENTS = 8  #: clients reading at once through serve to the far device
INFLIGHT = (1, 8)  #: --max-inflight compared


def _listening(serve: Child) -> int:
    """The port ``pymb serve`` printed it listens on (its first line:
    ``pymb serve: mbap://HOST:PORT -> UPSTREAM``)."""
    line = serve.readline(20)
    m = re.search(r"mbaps?://\S*:(\d+) ", line)
    if m is None:
        raise RuntimeError(f"pymb serve printed {line!r}")
    return int(m.group(1))


def _clients_at_once(port: int, clients: int, each: int) -> tuple[float, list[float]]:
    """``clients`` threads, each on its own kept connection reading ``each``
    times one after another: the wall time for all, every read's latency."""
    lat: list[float] = []
    socks = []
    for _ in range(clients):
        s = socket.create_connection(("127.0.0.1", port))
        s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        socks.append(s)
    failed: list[BaseException] = []

    def one(sock: socket.socket) -> None:
        try:
            lat.extend(_through(sock, each))
        except (OSError, RuntimeError) as e:
            failed.append(e)

    threads = [threading.Thread(target=one, args=(s,)) for s in socks]
    t = time.perf_counter()
    for th in threads:
        th.start()
    for th in threads:
        th.join(120)
    wall = time.perf_counter() - t
    for s in socks:
        s.close()
    if failed:
        raise RuntimeError(f"through pymb serve --tcp: {failed[0]}")
    return wall, lat


def _pipelined(opts: Any, children: Children) -> dict[str, Any]:
    """Eight clients at once through serve to a Modbus TCP device 2 ms away,
    one transaction at a time and eight in flight, turn about."""
    each = 40 if opts.quick else 250
    rounds = 1 if opts.quick else 4
    far = children.start("far Modbus TCP device", [
        sys.executable, "-m", "pymb.bench.farpeer", str(FAR_DELAY)], stdin=False)
    far_port = int(far.readline(20))
    serves = [children.start(f"pymb serve --max-inflight {n}", pymb_argv(
        "serve", "--tcp", f"127.0.0.1:{far_port}", "--max-inflight", str(n), "--timeout", "10",
        "--listen", "127.0.0.1:0", "--quiet"), stdin=False) for n in INFLIGHT]
    ports = [_listening(c) for c in serves]
    rates: dict[int, list[float]] = {n: [] for n in INFLIGHT}
    lats: dict[int, list[float]] = {n: [] for n in INFLIGHT}
    for i in range(rounds):
        order = list(zip(INFLIGHT, ports, strict=True))
        for n, port in order if i % 2 == 0 else order[::-1]:
            wall, lat = _clients_at_once(port, CLIENTS, each)
            rates[n].append(CLIENTS * each / wall)
            lats[n] += lat
    us = 1e6
    rows = [{"max_inflight": n, "reads": len(lats[n]),
             "reads_per_s": round(statistics.median(rates[n])),
             "p50_us": round(percentile(lats[n], 0.5) * us, 1),
             "p99_us": round(percentile(lats[n], 0.99) * us, 1)} for n in INFLIGHT]
    return {"delay_ms": FAR_DELAY * 1e3, "clients": CLIENTS, "rows": rows,
            "speedup_x": round(rows[-1]["reads_per_s"] / rows[0]["reads_per_s"], 2)}


def run_section(opts: Any, children: Children) -> dict[str, Any]:
    """Measure; returns the section's result (JSON-able)."""
    from pymb.fleet.broker import make_certificates
    n = 300 if opts.quick else 1000
    rounds = 1 if opts.quick else 15
    opts.say(f"serve: {rounds} round(s) of {n} reads, direct and through pymb serve")
    # one simulator a way: a line has one master
    # (no --baud: no wire emulation; --any-speed: whatever speed the line is set to)
    sims = children.sims([["coolpro:40,gap=0", "--any-speed", "--seed", "0"]] * 3)
    with tempfile.TemporaryDirectory(prefix="pymb-bench-serve-") as tmp:
        certs = make_certificates(tmp)
        plain = children.start("pymb serve", pymb_argv(
            "serve", "--port", sims[1].port, "--baud", "115200", "--listen", "127.0.0.1:0",
            "--quiet"), stdin=False)
        secure = children.start("pymb serve --tls", pymb_argv(
            "serve", "--port", sims[2].port, "--baud", "115200", "--listen", "127.0.0.1:0",
            "--tls", "--cert", certs.server_cert, "--key", certs.server_key, "--ca", certs.ca,
            "--quiet"), stdin=False)
        ports = [_listening(c) for c in (plain, secure)]
        ctx = ssl.create_default_context(ssl.Purpose.SERVER_AUTH, cafile=certs.ca)
        ctx.load_cert_chain(certs.client_cert, certs.client_key)
        sock = socket.create_connection(("127.0.0.1", ports[0]))
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        raw = socket.create_connection(("127.0.0.1", ports[1]))
        raw.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        tls = ctx.wrap_socket(raw, server_hostname="127.0.0.1")
        try:
            _through(sock, 50)
            _through(tls, 50)
            direct: list[float] = []
            served: list[float] = []
            secured: list[float] = []
            cpu_plain: list[float] = []
            cpu_tls: list[float] = []
            for i in range(rounds):
                direct += _direct(sims[0].port, n)
                # plain and TLS turn about, which goes first too: each round's
                # pair ran under the same load, and its ratio is one sample
                ways = [(sock, plain, served, cpu_plain), (tls, secure, secured, cpu_tls)]
                for conn, child, lat, cpu in ways if i % 2 == 0 else ways[::-1]:
                    c0 = _cpu(child.pid)
                    lat += _through(conn, n)
                    cpu.append((_cpu(child.pid) - c0) / n)
        finally:
            tls.close()
            sock.close()
    opts.say(f"serve: {CLIENTS} clients at once to a Modbus TCP device "
             f"{FAR_DELAY * 1e3:g} ms away, --max-inflight {' and '.join(map(str, INFLIGHT))}")
    pipelined = _pipelined(opts, children)
    us = 1e6
    rows = [{"way": way, "reads": len(v), "p50_us": round(percentile(v, 0.5) * us, 1),
             "p99_us": round(percentile(v, 0.99) * us, 1)}
            for way, v in (("direct (pymb RtuClient)", direct),
                           ("through pymb serve", served),
                           ("through pymb serve, TLS", secured))]
    plain_cpu = statistics.median(cpu_plain) * us
    tls_cpu = statistics.median(cpu_tls) * us
    ratios = [t / p for p, t in zip(cpu_plain, cpu_tls, strict=True) if p > 0]
    return {
        "rows": rows,
        "added_p99_us": round((percentile(served, 0.99) - percentile(direct, 0.99)) * us, 1),
        "added_p99_tls_us": round((percentile(secured, 0.99) - percentile(direct, 0.99)) * us, 1),
        "serve_cpu_us": round(plain_cpu, 1),
        "serve_cpu_tls_us": round(tls_cpu, 1),
        "tls_cpu_x": round(statistics.median(ratios), 2) if ratios else None,
        "tls_cpu_x_rounds": [round(x, 2) for x in ratios],
        "pipelined": pipelined,
        "note": "pymb serve's CPU per read from /proc (every thread's schedstat): medians of "
                "rounds; TLS / plain is the median of each round's ratio",
    }


def targets(result: dict[str, Any]) -> list[tuple[str, str, float | None, str, bool | None]]:
    """(what, goal, measured, unit, met) for the serve section."""
    added = result.get("added_p99_us")
    x = result.get("tls_cpu_x")
    return [
        ("pymb serve: latency added, p99", "<= 1000 us", added, "us",
         None if added is None else added <= 1000),
        ("pymb serve: CPU per read, TLS / plain", "<= 1.20", x, "x",
         None if x is None else x <= 1.20),
    ]


def tables(result: dict[str, Any]) -> list[Table]:
    """The section's table for the report."""
    rows = [[r["way"], f"{r['reads']:,}", fmt_time(r["p50_us"]), fmt_time(r["p99_us"])]
            for r in result["rows"]]
    main = Table(
        "pymb serve: a telemetry read direct and through pymb serve",
        "simulated CoolPro on a pty, no wire emulation; a plain socket client on a kept "
        "connection",
        ["way", "reads", "p50", "p99"], rows, [False, True, True, True],
        [f"latency added by pymb serve, p99: {fmt_time(result['added_p99_us'])} "
         f"(TLS: {fmt_time(result['added_p99_tls_us'])})",
         f"pymb serve's CPU per read: {fmt_time(result['serve_cpu_us'])} plain, "
         f"{fmt_time(result['serve_cpu_tls_us'])} TLS ({fmt_x(result['tls_cpu_x'])})"])
    return [main, *_pipelined_tables(result.get("pipelined"))]


def _pipelined_tables(p: dict[str, Any] | None) -> list[Table]:
    if not p:
        return []
    rows = [[str(r["max_inflight"]), f"{r['reads']:,}", f"{r['reads_per_s']:,}",
             fmt_time(r["p50_us"]), fmt_time(r["p99_us"])] for r in p["rows"]]
    return [Table(
        "pymb serve --tcp: requests in flight to a Modbus TCP device",
        f"{p['clients']} clients reading at once on kept connections; the device answers "
        f"each read {p['delay_ms']:g} ms after it arrives",
        ["--max-inflight", "reads", "reads/s", "p50", "p99"], rows,
        [True, True, True, True, True],
        [f"reads per second, {p['rows'][-1]['max_inflight']} in flight / 1: "
         f"{fmt_x(p['speedup_x'])}"])]
