"""The logger: several buses, several devices each, every bus in its own
thread, every sample time-stamped, every fault recorded as an event.

A bus is polled as fast as its wire allows (``interval = 0``) or every
``interval`` seconds on a drift-free schedule (slot k starts at
``start + k * interval``; a slot missed because a read ran long is skipped
and counted, not crammed in). A bus whose port fails is closed and reopened
with a doubling backoff (0.5 s to 30 s) while the other buses keep logging.

Configuration, as flags (one bus) or a TOML file (any number)::

    [output]
    format = "sqlite"          # sqlite | csv | jsonl | influx
    path = "pymb.sqlite"       # "-" for stdout (csv, jsonl)
    max_mb = 500               # optional: delete the oldest data past this size
    max_age_days = 30          # optional: ... or past this age
    on_change = false          # optional: store by exception (SQLite)
    heartbeat_s = 60           # ... every channel at least this often
    deadband = { temperature_c = 0.2, humidity_pct = 1 }   # ... engineering units

    [[bus]]
    name = "line1"
    port = "/dev/ttyUSB0"      # or tcp = "192.168.1.50:502", or
                               # rtu_over_tcp = "192.168.1.60:4001" (a raw serial server)
    baud = 9600
    parity = "N"
    timeout = 1.0
    interval = 0               # seconds between polls; 0 = as fast as the wire allows

    [[bus.device]]
    type = "coolpro"           # coolpro | hub
    address = 40
    name = "psu-a"             # optional

    [[bus.device]]
    type = "hub"
    address = 250
    channels = 100
    humidity_unit = 0.1        # or a list, one per channel

The package: :mod:`~pymb.logger.config` (buses, devices, output; the TOML
file), :mod:`~pymb.logger.poller` (a bus's thread), :mod:`~pymb.logger.logger`
(the run: pollers, the writer, the summary). The device syntax lives with the
devices (:mod:`pymb.devices.spec`), the status line and the joining of the
file, the flags and ``[mqtt]`` with the command line (:mod:`pymb.commands`).
"""

from __future__ import annotations

from pymb.client import unresolved
from pymb.devices.spec import (
    DEVICE_KEYS,
    DEVICE_SYNTAX,
    DEVICE_TYPES,
    DeviceConfig,
    closest,
    default_address,
    device_parts,
    parse_device,
)
from pymb.logger.config import BusConfig, LogConfig, check_buses, load_config
from pymb.logger.logger import Logger, Summary
from pymb.store import FAULT_KINDS, check_output, is_pymb_database

__all__ = [
    "DEVICE_KEYS",
    "DEVICE_SYNTAX",
    "DEVICE_TYPES",
    "FAULT_KINDS",
    "BusConfig",
    "DeviceConfig",
    "LogConfig",
    "Logger",
    "Summary",
    "check_buses",
    "check_output",
    "closest",
    "default_address",
    "device_parts",
    "is_pymb_database",
    "load_config",
    "parse_device",
    "unresolved",
]
