"""``pymb demo``: pymb's main job on a built-in default, with no hardware.

Starts a simulated CoolPro and a simulated sensor hub, each on its own
pseudo-terminal and each in its own process, emulating a 115200 bit/s line
(every frame takes its real wire time) with a few faults switched on; logs
both at full speed into a SQLite file with the live status line; then prints
what was achieved against what the wire allows, the CPU used, the faults
seen, where the file is and a query to try.
"""

from __future__ import annotations

import argparse
import errno
import math
import os
import sqlite3
import sys
import tempfile
import time
from pathlib import Path

from pymb.commands.demo_mqtt import run_with_mqtt
from pymb.commands.status import StatusLine
from pymb.errors import InvalidArgument
from pymb.fleet.session import require_paho
from pymb.logger import BusConfig, DeviceConfig, LogConfig, Logger
from pymb.sim import SimulatorProcess
from pymb.store.faults import storage_error, vanished
from pymb.store.guard import check_output
from pymb.store.records import FAULT_KINDS
from pymb.store.reserve import Reserve
from pymb.store.summary import event_counts

BAUD = 115200


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Arguments of ``pymb demo``."""
    p.add_argument("--seconds", type=float, default=10.0, help="how long to log (default 10)")
    p.add_argument("--out", metavar="FILE.sqlite",
                   help="database to write (default: a new file in the temp directory)")
    p.add_argument("--baud", type=int, default=BAUD, choices=[9600, 19200, 38400, 57600, 115200],
                   help=f"emulated line speed (default {BAUD})")
    p.add_argument("--quiet", action="store_true", help="no live status line")
    p.add_argument("--mqtt", nargs="?", const="auto", metavar="URL",
                   help="also publish every sample over MQTT (needs pymb-modbus[mqtt]): to URL, or "
                        "without one to a broker on 127.0.0.1:1883 or a mosquitto started "
                        "for the demo")


def run(args: argparse.Namespace) -> int:
    """Simulate, log, summarise."""
    if not (math.isfinite(args.seconds) and args.seconds > 0):
        raise InvalidArgument(f"--seconds must be more than 0, got {args.seconds:g}")
    if args.mqtt:
        require_paho()  # before any simulator starts
    # The process id too: two demos started in the same second (parallel CI
    # jobs) must not log into one file.
    out = args.out or os.path.join(
        tempfile.gettempdir(), time.strftime("pymb-demo-%Y%m%d-%H%M%S") + f"-{os.getpid()}.sqlite")
    baud = str(args.baud)
    sims = [
        SimulatorProcess(["coolpro", "--baud", baud, "--seed", "1",
                          "--fault", "bad_crc:0.002", "--fault", "no_reply:0.001"],
                         quiet=True),
        SimulatorProcess(["hub", "--baud", baud, "--seed", "2", "--fault", "busy:0.02"],
                         quiet=True),
    ]
    # before the simulators start: one line, nothing else (the demo writes SQLite)
    check_output("sqlite", out, choosable=False)
    if vanished(Path(out), made=False) is not None:  # no such folder: exit 5, as pymb log
        raise storage_error(Path(out), FileNotFoundError(errno.ENOENT, "no such directory"),
                            opening=True)

    def say(message: str) -> None:
        if not args.quiet:
            print(message, file=sys.stderr)

    started = time.time()  # the faults of this run: --out may hold an earlier run's
    try:
        for s in sims:
            s.start()
        psu = BusConfig("psu", sims[0].port, baud=args.baud, timeout=0.2,
                        devices=[DeviceConfig("coolpro", 40, "coolpro-40")])
        sensors = BusConfig("sensors", sims[1].port, baud=args.baud, timeout=1.0,
                            devices=[DeviceConfig("hub", 1, "hub-1")])
        say(f"pymb demo: simulated CoolPro on {sims[0].port}, sensor hub on {sims[1].port}, "
            f"{args.baud} bit/s emulated; logging for {args.seconds:g} s to {out}")
        cfg = LogConfig([psu, sensors], "sqlite", out)
        mqtt_lines: list[str] = []
        if args.mqtt:
            summary, mqtt_lines = run_with_mqtt(cfg, args.mqtt, args.seconds,
                                                None if args.quiet else sys.stderr, say)
        else:
            summary = Logger(cfg, tick=None if args.quiet else StatusLine(sys.stderr)).run(
                args.seconds)
    finally:
        for s in sims:
            s.stop()
        # The reserve is room for a running logger's trim on a full disk; the
        # demo's log is over, so it would only be 4 MB left in the folder.
        Reserve(Path(out)).give_up()
    faults = _faults(out, started)
    print(f"\npymb demo: {summary.samples:,} samples in {summary.elapsed:.1f} s, "
          f"{summary.cpu:.2f} s of CPU ({100 * summary.cpu / summary.elapsed:.0f}% of one core)")
    for bus in (psu, sensors):
        d = bus.devices[0]
        n = summary.by_device.get(d.name, 0)
        rate = n / summary.elapsed
        limit = 1.0 / bus.wire_time(d)
        what = {"telemetry": "telemetry reads", "sweep": "700-register sweeps"}[d.groups[0]]
        print(f"  {d.name:11s} {n:6,} {what} = {rate:7.1f}/s; the wire allows "
              f"{limit:7.1f}/s ({100 * rate / limit:.0f}%)")
    print(f"  faults seen: {summary.faults}" + (f" ({faults})" if faults else ""))
    for line in mqtt_lines:
        print(line)
    print(f"  database:    {out}")
    print("  try:         sqlite3 " + out + " \\\n"
          "                 \"SELECT time, channel, temperature_c, humidity_pct FROM hub_readings"
          " WHERE channel <= 3 ORDER BY time_utc DESC LIMIT 6\"")
    return 0


def _faults(path: str, since: float) -> str:
    try:
        rows = event_counts(path, since=since)
    except (sqlite3.Error, InvalidArgument):
        return ""
    return ", ".join(f"{n} {kind}" for kind, n in rows if kind in FAULT_KINDS)
