"""``pymb log``: log devices to SQLite (default), CSV or JSON Lines.

Exit codes at the end of a run (``--seconds``, SIGINT or SIGTERM): 0; 3 if
some device never delivered a sample; 4 if some bus never opened its port
(the summary says which); 5 if the output could not be written.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from pymb.commands._common import DEVICE_HELP
from pymb.errors import InvalidArgument
from pymb.fleet.config import KEYS, PASSWORD_ENV, PROFILES, MqttConfig
from pymb.logger import (
    BusConfig,
    DeviceConfig,
    LogConfig,
    Logger,
    load_config,
    parse_device,
)
from pymb.store import FORMATS, OnChange


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Arguments of ``pymb log``."""
    p.add_argument("devices", nargs="*", metavar="DEVICE",
                   help=f"{DEVICE_HELP}; several on one bus (--port or --tcp)")
    p.add_argument("--config", metavar="FILE.toml",
                   help="buses, devices and output from a TOML file (see the README)")
    p.add_argument("--port", metavar="PATH", help="serial port of a single bus")
    p.add_argument("--tcp", metavar="HOST:PORT", help="Modbus TCP gateway of a single bus")
    p.add_argument("--rtu-over-tcp", metavar="HOST:PORT",
                   help="RTU-over-TCP (raw serial server) of a single bus")
    p.add_argument("--device", action="append", default=[], metavar="DEVICE",
                   help="the same as a DEVICE argument (repeatable)")
    p.add_argument("--baud", type=int, default=9600)
    p.add_argument("--parity", default="N", choices=["N", "E", "O"])
    p.add_argument("--timeout", type=float, default=1.0, help="reply timeout, seconds")
    p.add_argument("--interval", type=float, default=0.0,
                   help="seconds between polls (default 0: as fast as the wire allows)")
    p.add_argument("--format", choices=FORMATS, help="output format (default sqlite)")
    p.add_argument("--out", metavar="PATH",
                   help="output file; '-' for stdout (csv, jsonl, influx); default "
                        "pymb-YYYYmmdd-HHMMSS.sqlite")
    p.add_argument("--max-mb", type=_positive, metavar="MB",
                   help="SQLite: keep the database and its WAL under this size, deleting the "
                        "oldest data (at least 1)")
    p.add_argument("--max-age-days", type=_positive, metavar="DAYS",
                   help="SQLite: delete data older than this")
    p.add_argument("--on-change", action="store_true",
                   help="SQLite: store a hub channel (or a CoolPro sample) only when a value "
                        "moved past its deadband, a state changed, or its heartbeat came")
    p.add_argument("--deadband", action="append", default=[], metavar="QUANTITY=AMOUNT",
                   help="with --on-change: e.g. temperature_c=0.2 (engineering units; "
                        "default 0: any change); repeat for several")
    p.add_argument("--heartbeat", type=_positive, metavar="SECONDS",
                   help="with --on-change: store every channel at least this often "
                        "(default 60)")
    p.add_argument("--seconds", type=float, help="stop after this long (default: until Ctrl-C)")
    p.add_argument("--quiet", action="store_true", help="no status line (for services)")
    add_mqtt_arguments(p)


def add_mqtt_arguments(p: argparse.ArgumentParser) -> None:
    """The ``--mqtt*`` flags (TOML: the ``[mqtt]`` table, keys of the same names)."""
    g = p.add_argument_group("forwarding to an MQTT broker (needs pymb[mqtt]; SQLite output)")
    g.add_argument("--mqtt", metavar="URL",
                   help="mqtt://HOST[:PORT] or mqtts://HOST[:PORT] (TLS): publish every sample")
    g.add_argument("--mqtt-profile", choices=PROFILES, help="plain JSON (default) or sparkplug")
    g.add_argument("--mqtt-node", metavar="NAME", help="edge node name (default: the host name)")
    g.add_argument("--mqtt-group", metavar="NAME", help="Sparkplug group (default pymb)")
    g.add_argument("--mqtt-prefix", metavar="PREFIX",
                   help="plain topics {prefix}/{node}/{device} (default pymb)")
    g.add_argument("--mqtt-user", metavar="NAME", help="user name")
    g.add_argument("--mqtt-password-file", metavar="FILE",
                   help=f"the password's file (or ${PASSWORD_ENV}; never on the command line)")
    g.add_argument("--mqtt-ca", metavar="FILE", help="CA certificate(s) to verify the broker")
    g.add_argument("--mqtt-cert", metavar="FILE", help="client certificate (with --mqtt-key)")
    g.add_argument("--mqtt-key", metavar="FILE", help="client certificate's private key")
    g.add_argument("--mqtt-drain", metavar="SECONDS",
                   help="on a clean stop, keep sending what is left for at most this long "
                        "(default 5; the rest goes with the next run)")
    g.add_argument("--mqtt-primary-host", metavar="ID",
                   help="Sparkplug: publish only while the primary host application ID says "
                        "online on spBv1.0/STATE/ID (the samples wait in the database)")


def mqtt_from(args: argparse.Namespace, base: MqttConfig | None) -> MqttConfig | None:
    """The [mqtt] table of the TOML file, overridden by the ``--mqtt*`` flags."""
    keys = [k for k in KEYS if k not in ("catchup_rate", "keepalive")]
    given = {k: getattr(args, "mqtt" if k == "url" else f"mqtt_{k}") for k in keys}
    given = {k: v for k, v in given.items() if v is not None}
    if "drain" in given:  # its range is MqttConfig's to check
        try:
            given["drain"] = float(given["drain"])
        except ValueError:
            raise InvalidArgument(f"--mqtt-drain needs a number of seconds, got "
                                  f"{given['drain']!r}") from None
    if base is None and not given:
        return None
    if base is None and "url" not in given:
        raise InvalidArgument("the --mqtt-* options need --mqtt URL (or [mqtt] url in the TOML)")
    table = {} if base is None else {k: getattr(base, k) for k in KEYS}
    return MqttConfig(**{**table, **given})


def _positive(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (value > 0 and math.isfinite(value)):
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text}")
    return value


def _on_change(args: argparse.Namespace, cfg: LogConfig) -> None:
    if not args.on_change:
        if args.deadband or args.heartbeat is not None:
            raise InvalidArgument("--deadband and --heartbeat go with --on-change")
        return
    bands = dict(cfg.on_change.deadband) if cfg.on_change else {}
    for spec in args.deadband:
        name, _, amount = spec.partition("=")
        try:
            bands[name.strip()] = float(amount)
        except ValueError:
            raise InvalidArgument(f"--deadband takes QUANTITY=AMOUNT, got {spec!r}") from None
    heartbeat = args.heartbeat or (cfg.on_change.heartbeat if cfg.on_change else 60.0)
    cfg.on_change = OnChange(heartbeat, bands)


def config_from(args: argparse.Namespace) -> LogConfig:
    """The LogConfig the arguments describe."""
    specs = list(args.devices) + list(args.device)
    if args.config:
        if args.port or args.tcp or args.rtu_over_tcp or specs:
            raise InvalidArgument("give either --config or --port/--tcp with devices, not both")
        cfg = load_config(args.config)
    else:
        if sum(bool(x) for x in (args.port, args.tcp, args.rtu_over_tcp)) > 1:
            raise InvalidArgument("give one of --port, --tcp or --rtu-over-tcp")
        if not (args.port or args.tcp or args.rtu_over_tcp) or not specs:
            raise InvalidArgument("name a bus and its devices: pymb log coolpro:40 hub:250 "
                                  "--port PATH (or --tcp HOST:PORT); or --config FILE")
        cfg = single_bus_config(args.port, args.tcp, [parse_device(s) for s in specs],
                                baud=args.baud, parity=args.parity, timeout=args.timeout,
                                interval=args.interval, rtu_over_tcp=args.rtu_over_tcp)
        cfg.path = ""
    if args.format:
        cfg.format = args.format
    if args.out:
        cfg.path = args.out
    elif not cfg.path or (not args.config and cfg.format == "sqlite"):
        cfg.path = default_path() if cfg.format == "sqlite" else "-"
    if args.max_mb is not None:
        cfg.max_bytes = int(args.max_mb * 1e6)
    if args.max_age_days is not None:
        cfg.max_age = args.max_age_days * 86400
    cfg.mqtt = mqtt_from(args, cfg.mqtt)
    if cfg.mqtt is not None and cfg.format != "sqlite":
        raise InvalidArgument("--mqtt forwards from the SQLite database (the outbox): "
                              "use --format sqlite")
    _on_change(args, cfg)
    return cfg


def run(args: argparse.Namespace) -> int:
    """Log until Ctrl-C / SIGTERM (or --seconds), then print the summary."""
    if args.seconds is not None and not args.seconds > 0:
        raise InvalidArgument(f"--seconds must be more than 0, got {args.seconds:g}")
    cfg = config_from(args)
    if cfg.mqtt is not None:
        from pymb.fleet.run import log_and_forward
        return log_and_forward(cfg, cfg.mqtt, seconds=args.seconds, quiet=args.quiet)
    logger = Logger(cfg, status=None if args.quiet else sys.stderr)
    s = logger.run(args.seconds)
    skipped = f", {s.skipped_slots} interval slot(s) skipped" if s.skipped_slots else ""
    lines = [f"logged {s.samples:,} samples ({s.rate:,.1f}/s) and {s.events} events "
             f"({s.faults} faults{skipped}) in {s.elapsed:.1f} s to {s.path}"]
    lines += s.problems()
    problems = s.problems()
    if not args.quiet or problems:
        for line in lines if not args.quiet else problems:
            print(("pymb log: " if line in problems else "") + line, file=sys.stderr)
    return s.exit_code


def single_bus_config(port: str | None, tcp: str | None,
                      devices: Sequence[str | DeviceConfig], *,
                      baud: int = 9600, parity: str = "N", timeout: float = 1.0,
                      interval: float = 0.0, fmt: str = "sqlite", path: str = "pymb.sqlite",
                      max_mb: float | None = None, max_age_days: float | None = None,
                      name: str = "bus1", rtu_over_tcp: str | None = None) -> LogConfig:
    """A LogConfig for one bus from command-line style arguments."""
    bus = BusConfig(name, port, tcp, baud, parity, timeout, interval,
                    [d if isinstance(d, DeviceConfig) else parse_device(d) for d in devices],
                    rtu_over_tcp)
    return LogConfig([bus], fmt, path, None if max_mb is None else int(max_mb * 1e6),
                     None if max_age_days is None else max_age_days * 86400)


def default_path() -> str:
    """``pymb-YYYYmmdd-HHMMSS.sqlite`` in the current directory."""
    return str(Path.cwd() / time.strftime("pymb-%Y%m%d-%H%M%S.sqlite"))
