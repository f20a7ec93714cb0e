"""``pymb serve``: a Modbus TCP server (and Modbus/TCP Security with
``--tls``) in front of one upstream line, shared by many clients."""

from __future__ import annotations

import argparse
import asyncio
import os
import signal
import ssl
import sys

from pymb.client import TcpClient
from pymb.client.address import parse_host_port
from pymb.commands._common import add_connection_args, make_client, never_a_line
from pymb.errors import InvalidArgument, ModbusConnectionError
from pymb.serve import Server, UnitMap, Upstream
from pymb.serve.pipeline import DEFAULT_MAX_INFLIGHT, PipelinedUpstream

__all__ = ["add_arguments", "run", "tls_server_context"]

MAX_INFLIGHT = 255  #: the most --max-inflight takes


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Arguments of ``pymb serve``."""
    add_connection_args(p, timeout=1.0, tls=False)  # --cert/--key/--ca: the server's own
    p.add_argument("--listen", default=None, metavar="HOST:PORT",
                   help="where to accept Modbus TCP clients (default 127.0.0.1:502, with "
                        "--tls 127.0.0.1:802, Modbus/TCP Security's port; "
                        "0.0.0.0:502 for every interface; port 0 picks a free one)")
    p.add_argument("--unit", action="append", default=[], metavar="LISTEN=UPSTREAM",
                   help="route a unit id to another upstream unit (repeatable); others pass "
                        "through unchanged")
    p.add_argument("--max-inflight", type=int, default=None, metavar="N",
                   help="with --tcp: requests in flight to the upstream at once, each under "
                        f"its own transaction id (default {DEFAULT_MAX_INFLIGHT}; 1: one at a "
                        "time); a serial line always takes one at a time")
    p.add_argument("--max-clients", type=int, default=64, metavar="N",
                   help="clients connected at once (default 64); more are refused")
    tls = p.add_argument_group("Modbus/TCP Security (TLS, client certificates required)")
    tls.add_argument("--tls", action="store_true",
                     help="accept only TLS clients with a certificate signed by --ca")
    tls.add_argument("--cert", metavar="FILE", help="the server's certificate (PEM)")
    tls.add_argument("--key", metavar="FILE", help="its private key (PEM)")
    tls.add_argument("--ca", metavar="FILE", help="the CA that signs client certificates (PEM)")
    tls.add_argument("--write-roles", default="", metavar="ROLE[,ROLE...]",
                     help="roles (from the client certificate's Modbus role extension) that may "
                          "write; every other client may only read")
    up = p.add_argument_group("the upstream's Modbus/TCP Security (with --tcp mbaps://HOST[:PORT])")
    up.add_argument("--upstream-ca", dest="tls_ca", metavar="FILE",
                    help="the CA that signed the upstream's certificate (default: the system's)")
    up.add_argument("--upstream-cert", dest="tls_cert", metavar="FILE",
                    help="pymb serve's client certificate for the upstream (PEM)")
    up.add_argument("--upstream-key", dest="tls_key", metavar="FILE",
                    help="its private key (PEM)")
    up.add_argument("--upstream-server-name", dest="tls_server_name", metavar="NAME",
                    help="the name the upstream's certificate must be made for (default: its host)")
    p.add_argument("--quiet", action="store_true", help="no event lines")


def tls_server_context(cert: str | None, key: str | None, ca: str | None) -> ssl.SSLContext:
    """A TLS 1.2+ server context that requires a client certificate signed by
    ``ca``; a missing or unreadable file is said in one line."""
    if not cert or not key or not ca:
        flag = "--cert" if not cert else "--key" if not key else "--ca"
        raise InvalidArgument(f"--tls needs {flag} FILE")
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    ctx.minimum_version = ssl.TLSVersion.TLSv1_2
    ctx.verify_mode = ssl.CERT_REQUIRED
    try:
        ctx.load_cert_chain(cert, key)
    except (OSError, ssl.SSLError) as e:
        raise InvalidArgument(f"--cert {cert} / --key {key}: {_why(e)}") from None
    try:
        ctx.load_verify_locations(cafile=ca)
    except (OSError, ssl.SSLError) as e:
        raise InvalidArgument(f"--ca {ca}: {_why(e)}") from None
    return ctx


def _why(e: BaseException) -> str:
    if isinstance(e, OSError) and e.strerror:
        return e.strerror
    return str(getattr(e, "reason", None) or e)


def run(args: argparse.Namespace) -> int:
    """Serve until SIGINT or SIGTERM; exit 0."""
    listen = args.listen or ("127.0.0.1:802" if args.tls else "127.0.0.1:502")
    host, port = parse_host_port(listen, what="--listen")
    units = UnitMap.parse(args.unit)
    if args.max_clients < 1:
        raise InvalidArgument(f"--max-clients must be at least 1, got {args.max_clients}")
    given = [f for f, v in (("--cert", args.cert), ("--key", args.key), ("--ca", args.ca)) if v]
    if given and not args.tls:  # never a plaintext server the user meant to be TLS
        raise InvalidArgument(f"{'/'.join(given)} {'is' if len(given) == 1 else 'are'} for "
                              "the TLS server: give --tls too "
                              "(or --upstream-ca/--upstream-cert/--upstream-key for an "
                              "mbaps:// upstream)")
    tls = tls_server_context(args.cert, args.key, args.ca) if args.tls else None
    roles = frozenset(r.strip() for r in args.write_roles.split(",") if r.strip())
    if roles and tls is None:
        raise InvalidArgument("--write-roles needs --tls (roles come from client certificates)")
    if args.max_inflight is not None and not 1 <= args.max_inflight <= MAX_INFLIGHT:
        raise InvalidArgument(f"--max-inflight must be 1..{MAX_INFLIGHT}, "
                              f"got {args.max_inflight}")
    what = never_a_line(args.port) if args.port else None
    if what is not None:
        raise InvalidArgument(f"--port {args.port} is {what}, not a serial port")
    try:
        line = make_client(args)
    except InvalidArgument as e:  # the client's options are --upstream-* here
        text = str(e)
        for flag in ("--ca", "--cert", "--key", "--server-name"):
            text = text.replace(f"{flag} ", f"--upstream-{flag[2:]} ").replace(
                f"{flag}/", f"--upstream-{flag[2:]}/")
        raise InvalidArgument(text) from None
    # plain Modbus TCP takes several requests at once; an mbaps:// upstream
    # (TLS in the C client) stays one at a time, as every other line does
    pipelined = isinstance(line, TcpClient) and line.tls is None
    if args.max_inflight is not None and not pipelined:
        raise InvalidArgument("--max-inflight needs --tcp HOST:PORT, a plain Modbus TCP "
                              "upstream (any other line takes one transaction at a time)")

    def say(text: str) -> None:
        if not args.quiet:
            print(f"pymb serve: {text}", file=sys.stderr, flush=True)

    upstream: Upstream | PipelinedUpstream
    if isinstance(line, TcpClient) and pipelined:
        upstream = PipelinedUpstream(
            line.host, line.tcp_port, timeout=args.timeout, on_event=say,
            max_inflight=args.max_inflight or DEFAULT_MAX_INFLIGHT)
    else:
        upstream = Upstream(line, on_event=say)
    server = Server(upstream, host, port, units=units, max_clients=args.max_clients, tls=tls,
                    write_roles=roles, on_event=say)
    upstream_name = (f"{args.port} (ASCII)" if args.ascii else args.port or args.tcp
                     or args.rtu_over_tcp or f"{args.udp} (UDP)")
    # Two threads hand each request to each other: with Python's default 5 ms
    # switch interval, a thread that wants the GIL back can wait that long.
    sys.setswitchinterval(0.0002)
    return asyncio.run(_serve(server, upstream, upstream_name))


def _counted(n: int, word: str) -> str:
    """``n`` and ``word``, plural unless ``n`` is 1: "1 connection", "2 connections"."""
    return f"{n:,} {word}" + ("" if n == 1 else "s")


async def _serve(server: Server, upstream: Upstream | PipelinedUpstream,
                 upstream_name: str) -> int:
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    try:
        await server.start()
    except OSError as e:
        raise ModbusConnectionError(
            f"cannot listen on {server.host}:{server.port}: {e.strerror or e}",
            port=f"{server.host}:{server.port}") from None
    upstream.start()
    scheme = "mbaps" if server.tls is not None else "mbap"
    # The one line on stdout: where clients connect (port 0 becomes the real one).
    host = f"[{server.host}]" if ":" in server.host else server.host  # an IPv6 address
    print(f"pymb serve: {scheme}://{host}:{server.port} -> {upstream_name}", flush=True)
    try:
        await server.serve_until(stop)
    finally:
        upstream.stop()
    st = server.stats
    unsent = upstream.unwanted + st.unsent  # (taken from the client or left in its buffer)
    print(f"pymb serve: {_counted(st.requests, 'request')} from "
          f"{_counted(st.connections, 'connection')}; "
          f"upstream: {upstream.sent:,} sent, {upstream.timeouts:,} unanswered, "
          f"{upstream.unreachable:,} while unreachable"
          + (f", {unsent:,} not sent (their clients had gone)" if unsent else "")
          + (f", {upstream.dropped:,} dropped at the stop" if upstream.dropped else ""),
          file=sys.stderr)
    if upstream.abandoned:
        # Its thread is still in a C wait on a silent device, which calls into
        # Python every 50 ms: the interpreter's shutdown must not meet it there.
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(0)
    return 0
