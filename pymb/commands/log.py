"""``pymb log``: log devices to SQLite (default), CSV or JSON Lines.

Exit codes at the end of a run (``--seconds``, SIGINT or SIGTERM): 0; 3 if
some device never delivered a sample; 4 if some bus never opened its port
(the summary says which); 5 if the output could not be written; 70 if a
bus's poller stopped on an internal error (a bug).
"""

from __future__ import annotations

import argparse
import math
import sys

from pymb.commands._common import (
    add_alias_args,
    add_ascii_arg,
    add_map_arg,
    add_mqtt_access,
    add_serial_args,
    add_tls_args,
    device_help,
)
from pymb.commands.forward import log_and_forward
from pymb.commands.logconfig import config_from
from pymb.commands.status import StatusLine, status_text
from pymb.errors import InvalidArgument
from pymb.fleet.config import PASSWORD_ENV, PROFILES, PROTOCOLS
from pymb.logger import Logger
from pymb.logger.config import COMMIT_BYTES, COMMIT_INTERVAL
from pymb.service.journal import echoing
from pymb.service.run import Service
from pymb.store import FORMATS, check_output, open_sink
from pymb.wire import DEFAULT_TIMEOUT


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Arguments of ``pymb log``."""
    p.add_argument("devices", nargs="*", metavar="DEVICE",
                   help=f"{device_help()}; several on one bus (--port or --tcp)")
    add_map_arg(p)
    p.add_argument("--config", metavar="FILE.toml",
                   help="buses, devices and output from a TOML file (see docs/cli.md)")
    p.add_argument("--port", metavar="PATH", help="serial port of a single bus")
    p.add_argument("--tcp", metavar="HOST:PORT",
                   help="Modbus TCP gateway of a single bus; mbaps://HOST[:PORT] for Modbus/TCP "
                        "Security (TLS, port 802)")
    p.add_argument("--rtu-over-tcp", metavar="HOST:PORT",
                   help="RTU-over-TCP (raw serial server) of a single bus")
    p.add_argument("--udp", metavar="HOST:PORT", help="Modbus over UDP device of a single bus")
    add_ascii_arg(p)
    p.add_argument("--device", action="append", default=[], metavar="DEVICE",
                   help="the same as a DEVICE argument (repeatable)")
    add_alias_args(p, note="; with one DEVICE")
    add_serial_args(p)
    p.add_argument("--timeout", type=float, default=DEFAULT_TIMEOUT, help="reply timeout, seconds")
    p.add_argument("--interval", type=float, default=0.0,
                   help="seconds between polls (default 0: as fast as the wire allows)")
    p.add_argument("--format", choices=FORMATS, help="output format (default sqlite)")
    p.add_argument("--out", metavar="PATH",
                   help="output file; '-' for stdout (csv, jsonl, influx); default: a new "
                        "pymb-YYYYmmdd-HHMMSS.sqlite here, stdout for the other formats")
    p.add_argument("--max-mb", type=_positive, metavar="MB",
                   help="SQLite: keep the database and its WAL under this size, deleting the "
                        "oldest data (at least 1)")
    p.add_argument("--max-age-days", type=_positive, metavar="DAYS",
                   help="SQLite: delete data older than this")
    p.add_argument("--commit-interval", type=_positive, metavar="SECONDS",
                   help=f"SQLite: commit at least this often (default {COMMIT_INTERVAL:g}; "
                        f"always when {COMMIT_BYTES // 1024} KB of registers wait): a power "
                        "cut loses what waits, more commits wear an SD card more "
                        "(docs/reliability.md)")
    p.add_argument("--on-change", action="store_true",
                   help="SQLite: store a hub channel (a CoolPro sample, a map device's group "
                        "reading) only when a value moved past its deadband, a state "
                        "changed, or its heartbeat came")
    p.add_argument("--deadband", action="append", default=[], metavar="NAME=AMOUNT",
                   help="with --on-change: a quantity (temperature_c=0.2) or a map "
                        "device's point (voltage_v=0.5), in engineering units, over the "
                        "map's deadband; default 0: any change; repeat for several")
    p.add_argument("--heartbeat", type=_positive, metavar="SECONDS",
                   help="with --on-change: store every channel (reading) at least this often "
                        "(default 60)")
    p.add_argument("--seconds", type=float, help="stop after this long (default: until Ctrl-C)")
    p.add_argument("--quiet", action="store_true", help="no status line (for services)")
    add_tls_args(p)
    add_mqtt_arguments(p)


def add_mqtt_arguments(p: argparse.ArgumentParser) -> None:
    """The ``--mqtt*`` flags (TOML: the ``[mqtt]`` table, keys of the same names)."""
    g = p.add_argument_group(
        "forwarding to an MQTT broker (needs pymb-modbus[mqtt]; SQLite output)")
    g.add_argument("--mqtt", metavar="URL",
                   help="mqtt://HOST[:PORT] or mqtts://HOST[:PORT] (TLS): publish every sample")
    g.add_argument("--mqtt-profile", choices=PROFILES, help="plain JSON (default) or sparkplug")
    g.add_argument("--mqtt-node", metavar="NAME", help="edge node name (default: the host name)")
    g.add_argument("--mqtt-group", metavar="NAME", help="Sparkplug group (default pymb)")
    g.add_argument("--mqtt-prefix", metavar="PREFIX",
                   help="plain topics {prefix}/{node}/{device} (default pymb)")
    add_mqtt_access(g, f"the password's file (or ${PASSWORD_ENV}; never on the command line)")
    g.add_argument("--mqtt-drain", metavar="SECONDS",
                   help="on a clean stop, keep sending what is left for at most this long "
                        "(default 5; the rest goes with the next run)")
    g.add_argument("--mqtt-start", choices=("oldest", "now"),
                   help="where a new outbox cursor (a broker, profile and node not seen "
                        "before) starts: every sample in the database (oldest, the default) "
                        "or those logged from now on")
    g.add_argument("--mqtt-protocol", choices=PROTOCOLS,
                   help="the MQTT version: 5 (default; the broker says when it refuses a "
                        "sample, which then stays in the database) or 3.1.1")
    g.add_argument("--allow-writes", metavar="PATTERN", action="append", default=[],
                   help="DEVICE/POINT (fnmatch, repeatable) that write commands on "
                        "{prefix}/{node}/{device}/set (Sparkplug: DCMD) may change "
                        "(default: nothing)")
    g.add_argument("--mqtt-primary-host", metavar="ID",
                   help="Sparkplug: publish only while the primary host application ID says "
                        "online on spBv1.0/STATE/ID (the samples wait in the database)")


def _positive(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (value > 0 and math.isfinite(value)):
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text}")
    return value


def run(args: argparse.Namespace) -> int:
    """Log until Ctrl-C / SIGTERM (or --seconds), then print the summary."""
    if args.seconds is not None and not args.seconds > 0:
        raise InvalidArgument(f"--seconds must be more than 0, got {args.seconds:g}")
    cfg, mqtt = config_from(args)
    service = Service(lambda: config_from(args), status_text)
    if mqtt is not None:
        code = log_and_forward(cfg, mqtt, seconds=args.seconds, quiet=args.quiet,
                               service=service)
        service.finish()
        return code
    check_output(cfg.format, cfg.path)
    sink = open_sink(cfg.format, cfg.path, max_bytes=cfg.max_bytes, max_age=cfg.max_age,
                     on_change=cfg.on_change)
    logger = Logger(cfg, sink=echoing(sink),
                    tick=service.tick(None if args.quiet else StatusLine(sys.stderr)))
    service.attach(logger)
    s = logger.run(args.seconds)
    lines = [s.headline()]
    lines += s.health()
    lines += s.problems()
    problems = s.problems()
    if not args.quiet or problems:
        for line in lines if not args.quiet else problems:
            print(("pymb log: " if line in problems else "") + line, file=sys.stderr)
    service.finish()
    return s.exit_code


