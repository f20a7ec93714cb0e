"""``pymb log``'s configuration, joined from its three sources: the TOML file
(buses and output: :mod:`pymb.logger.config`; ``[mqtt]``:
:mod:`pymb.fleet.config`), then the command-line flags over both."""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Sequence
from pathlib import Path

from pymb.client import TlsConfig
from pymb.commands._common import (
    alias_spec,
    ascii_line,
    never_a_line,
    serial_options,
    tls_for,
    tls_from_args,
)
from pymb.commands.sunspeccli import is_sunspec, sunspec_target
from pymb.devices.deviceconfig import DeviceConfig, KnownMaps, MapText, from_target, parse_device
from pymb.errors import InvalidArgument
from pymb.fleet.config import KEYS, MqttConfig, from_table
from pymb.logger.config import (
    DEFAULT_TOML_PATH,
    BusConfig,
    LogConfig,
    config_from_toml,
    read_toml,
    share_deadbands,
)
from pymb.store import OnChange
from pymb.store.mapcheck import check_stored_maps
from pymb.wire import DEFAULT_BAUD, DEFAULT_PARITY, DEFAULT_TIMEOUT

__all__ = ["config_from", "default_path", "load", "mqtt_from", "single_bus_config"]


def load(path: str | os.PathLike[str]) -> tuple[LogConfig, MqttConfig | None]:
    """A TOML configuration: its buses and output, and its ``[mqtt]`` table (None
    if it has none)."""
    cfg, mqtt, _ = _load(path)
    return cfg, mqtt


def _load(path: str | os.PathLike[str]) -> tuple[LogConfig, MqttConfig | None, bool]:
    """:func:`load`, and whether the file names the output's path."""
    doc = read_toml(path)
    cfg = config_from_toml(doc, path)
    table = doc.get("mqtt")
    return (cfg, None if table is None else from_table(table, str(path)),
            "path" in doc.get("output", {}))


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


def _on_change(args: argparse.Namespace, cfg: LogConfig) -> None:
    if not args.on_change:
        if args.deadband or args.heartbeat is not None:
            raise InvalidArgument("--deadband and --heartbeat go with --on-change")
        return
    given = {}
    for spec in args.deadband:
        name, _, amount = spec.partition("=")
        try:
            given[name.strip()] = float(amount)
        except ValueError:
            raise InvalidArgument(f"--deadband takes NAME=AMOUNT, got {spec!r}") from None
    bands = dict(cfg.on_change.deadband) if cfg.on_change else {}
    bands.update(share_deadbands(cfg.buses, given, True))
    heartbeat = args.heartbeat or (cfg.on_change.heartbeat if cfg.on_change else 60.0)
    cfg.on_change = OnChange(heartbeat, bands)


def config_from(args: argparse.Namespace) -> tuple[LogConfig, MqttConfig | None]:
    """The LogConfig the arguments describe, and where to forward (None: nowhere)."""
    specs = list(args.devices) + list(args.device)
    aliases = [f"--{a.replace('_', '-')}" for a in ("address", "channels", "humidity_unit")
               if getattr(args, a, None) is not None]
    udp: str | None = getattr(args, "udp", None)
    on_ascii: bool = getattr(args, "ascii", False)
    mqtt_table: MqttConfig | None = None
    serial_options(args)
    if args.config:
        if args.port or args.tcp or args.rtu_over_tcp or udp or on_ascii or specs:
            raise InvalidArgument("give either --config or --port/--tcp with devices, not both")
        if aliases:
            raise InvalidArgument(f"with --config, give {aliases[0]}'s value in the file's "
                                  "[[bus.device]] table")
        if getattr(args, "maps", None):
            raise InvalidArgument("with --config, name map files in the file: maps = [...]")
        if tls_from_args(args) is not None:
            raise InvalidArgument("with --config, give a bus's TLS settings in the file: "
                                  "[bus.tls]")
        cfg, mqtt_table, named = _load(args.config)
        if not named:  # the format's own default, once --format has had its say
            cfg.path = ""
    else:
        if sum(bool(x) for x in (args.port, args.tcp, args.rtu_over_tcp, udp)) > 1:
            raise InvalidArgument("give one of --port, --tcp, --rtu-over-tcp or --udp")
        ascii_line(args)
        if not (args.port or args.tcp or args.rtu_over_tcp or udp) or not specs:
            raise InvalidArgument("name a bus and its devices: pymb log coolpro:40 hub:250 "
                                  "--port PATH (or --tcp HOST:PORT); or --config FILE")
        known = KnownMaps()
        for f in getattr(args, "maps", None) or []:
            known.add_file(f, "--map")
        if aliases:
            if len(specs) != 1 or is_sunspec(specs[0]):
                raise InvalidArgument(f"{aliases[0]} is an alias for one device's own "
                                      "option: with several devices (or a SunSpec one), "
                                      "write it in the DEVICE, e.g. hub:250,channels=50")
            specs = [alias_spec(specs[0], args, known)]
        devices = [sunspec_device(args, s) if is_sunspec(s) else parse_device(s, known)
                   for s in specs]
        cfg = single_bus_config(args.port, args.tcp, devices,
                                baud=args.baud, parity=args.parity, timeout=args.timeout,
                                interval=args.interval, rtu_over_tcp=args.rtu_over_tcp,
                                udp=udp,
                                ascii=on_ascii,
                                tls=tls_for(args, args.tcp))
        cfg.path = ""
    for b in cfg.buses:  # a path that can never open: a mistake, not an adapter to wait for
        what = never_a_line(b.port) if b.port else None
        if what is not None:
            raise InvalidArgument(f"{args.config}: bus {b.name!r}: port {b.port} is {what}, "
                                  "not a serial port" if args.config else
                                  f"--port {b.port} is {what}, not a serial port")
    if args.format:
        cfg.format = args.format
    if args.out:
        cfg.path = args.out
    elif not cfg.path:
        cfg.path = "-" if cfg.format != "sqlite" else \
            DEFAULT_TOML_PATH if args.config else default_path()
    if args.max_mb is not None:
        cfg.max_bytes = int(args.max_mb * 1e6)
    if args.max_age_days is not None:
        cfg.max_age = args.max_age_days * 86400
    if getattr(args, "commit_interval", None) is not None:
        cfg.commit_interval = args.commit_interval
    for pattern in getattr(args, "allow_writes", None) or []:
        if "/" not in pattern:
            raise InvalidArgument(f"--allow-writes {pattern!r}: a pattern is DEVICE/POINT "
                                  "(fnmatch: meter-3/*)")
        cfg.allow_writes = (*cfg.allow_writes, pattern)
    mqtt = mqtt_from(args, mqtt_table)
    if mqtt is not None and cfg.format != "sqlite":
        raise InvalidArgument("--mqtt forwards from the SQLite database (the outbox): "
                              "use --format sqlite")
    if cfg.allow_writes and mqtt is None:
        raise InvalidArgument("write commands come over MQTT (the plain profile's set topics, "
                              "Sparkplug's DCMD): --allow-writes ([writes] allow) needs "
                              "--mqtt URL")
    _on_change(args, cfg)
    if cfg.format == "sqlite":  # at the start and before a SIGHUP reload
        check_stored_maps(cfg.path, {d.type: d.text.text for b in cfg.buses
                                     for d in b.devices})
    return cfg, mqtt


def sunspec_device(args: argparse.Namespace, spec: str) -> DeviceConfig:
    """A SunSpec device (``sunspec:1``): its map is found on the device now."""
    target, text = sunspec_target(args, spec)
    return from_target(target, MapText(target.map, text))


def single_bus_config(port: str | None, tcp: str | None,
                      devices: Sequence[str | DeviceConfig], *,
                      baud: int = DEFAULT_BAUD, parity: str = DEFAULT_PARITY,
                      timeout: float = DEFAULT_TIMEOUT,
                      interval: float = 0.0, fmt: str = "sqlite", path: str = "pymb.sqlite",
                      max_mb: float | None = None, max_age_days: float | None = None,
                      name: str = "bus1", rtu_over_tcp: str | None = None,
                      udp: str | None = None, ascii: bool = False,
                      tls: TlsConfig | None = None) -> LogConfig:
    """A LogConfig for one bus from command-line style arguments."""
    bus = BusConfig(name, port, tcp, baud, parity, timeout, interval,
                    [parse_device(d) if isinstance(d, str) else d for d in devices],
                    rtu_over_tcp, udp=udp, ascii=ascii, tls=tls)
    return LogConfig([bus], fmt, path, None if max_mb is None else int(max_mb * 1e6),
                     None if max_age_days is None else max_age_days * 86400)


def default_path() -> str:
    """``pymb-YYYYmmdd-HHMMSS.sqlite`` in the current directory."""
    return str(Path.cwd() / time.strftime("pymb-%Y%m%d-%H%M%S.sqlite"))
