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
import socket
import ssl
import statistics
import struct
import tempfile
import time
from typing import Any

from pymb.bench.procs import Children
from pymb.bench.table import Table, fmt_time, fmt_x
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
    if seen:
        return total / 1e9
    with open(f"/proc/{pid}/stat", encoding="ascii") as f:
        fields = f.read().rpartition(")")[2].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _pct(values: list[float], q: float) -> float:
    s = sorted(values)
    return s[min(len(s) - 1, int(q * len(s)))]


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
        ports = [int(c.readline(20).rsplit(":", 1)[1].split()[0]) for c in (plain, secure)]
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
    us = 1e6
    rows = [{"way": way, "reads": len(v), "p50_us": round(_pct(v, 0.5) * us, 1),
             "p99_us": round(_pct(v, 0.99) * us, 1)}
            for way, v in (("direct (pymb RtuClient)", direct),
                           ("through pymb serve", served),
                           ("through pymb serve, TLS", secured))]
    plain_cpu = statistics.median(cpu_plain) * us
    tls_cpu = statistics.median(cpu_tls) * us
    ratios = [t / p for p, t in zip(cpu_plain, cpu_tls, strict=True) if p > 0]
    return {
        "rows": rows,
        "added_p99_us": round((_pct(served, 0.99) - _pct(direct, 0.99)) * us, 1),
        "added_p99_tls_us": round((_pct(secured, 0.99) - _pct(direct, 0.99)) * us, 1),
        "serve_cpu_us": round(plain_cpu, 1),
        "serve_cpu_tls_us": round(tls_cpu, 1),
        "tls_cpu_x": round(statistics.median(ratios), 2) if ratios else None,
        "tls_cpu_x_rounds": [round(x, 2) for x in ratios],
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
    return [Table(
        "pymb serve: a telemetry read direct and through pymb serve",
        "simulated CoolPro on a pty, no wire emulation; a plain socket client on a kept "
        "connection",
        ["way", "reads", "p50", "p99"], rows, [False, True, True, True],
        [f"latency added by pymb serve, p99: {fmt_time(result['added_p99_us'])} "
         f"(TLS: {fmt_time(result['added_p99_tls_us'])})",
         f"pymb serve's CPU per read: {fmt_time(result['serve_cpu_us'])} plain, "
         f"{fmt_time(result['serve_cpu_tls_us'])} TLS ({fmt_x(result['tls_cpu_x'])})"])]
