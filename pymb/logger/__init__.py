"""The logger: several buses, several devices each, every serial bus in its
own thread and every map device on Modbus TCP in one loop of one thread,
every sample time-stamped, every fault recorded as an event.

A bus is polled as fast as its wire allows (``interval = 0``) or every
``interval`` seconds on a drift-free schedule (slot k starts at
``start + k * interval``; a slot missed because a read ran long is skipped
and counted, not crammed in). A bus whose port fails is closed and reopened
with a doubling backoff (0.5 s to 30 s) while the other buses keep logging.

Configuration, as flags (one bus) or a TOML file (any number): tables
``[output]`` (format, path, max_mb, max_age_days, on_change, heartbeat_s,
deadband), ``[[bus]]`` (name, port / tcp / rtu_over_tcp, baud, parity,
timeout, interval) and ``[[bus.device]]`` (type, address, name, channels,
humidity_unit); ``[mqtt]`` is the forwarder's. The example and the table of
keys are in the documentation (``docs/cli.md``, ``docs/examples/buses.toml``).

The package: :mod:`~pymb.logger.config` (buses, devices, output; the TOML
file), :mod:`~pymb.logger.poller` (a bus's thread), :mod:`~pymb.logger.tcploop`
(the one loop over the TCP buses' map devices, with :mod:`~pymb.logger.tcpunits`),
:mod:`~pymb.logger.logger`
(the run: pollers, the writer, the summary). The device syntax lives with the
devices (:mod:`pymb.devices.spec`, :mod:`pymb.devices.mapspec`), the status
line and the joining of the file, the flags and ``[mqtt]`` with the command
line (:mod:`pymb.commands`).
"""

from __future__ import annotations

from pymb.client import unresolved
from pymb.devices.deviceconfig import DeviceConfig, parse_device
from pymb.devices.spec import closest
from pymb.logger.config import BusConfig, LogConfig, check_buses, load_config
from pymb.logger.logger import Logger, RunSummary
from pymb.store import FAULT_KINDS, check_output, is_pymb_database

__all__ = [
    "FAULT_KINDS",
    "BusConfig",
    "DeviceConfig",
    "LogConfig",
    "Logger",
    "RunSummary",
    "check_buses",
    "check_output",
    "closest",
    "is_pymb_database",
    "load_config",
    "parse_device",
    "unresolved",
]
