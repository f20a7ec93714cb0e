"""What the subcommands share: connection arguments, the client they make,
and the text and JSON renderings of a reading."""

from __future__ import annotations

import argparse
import json
import math
import sys
from typing import Any

from pymb.client import Client, RtuClient, client_for_address
from pymb.devices import HUB, CoolProIdentity, CoolProTelemetry, HubReading, State
from pymb.devices.maps import COOLPRO

__all__ = ["add_connection_args", "make_client", "render", "to_json"]


def add_connection_args(p: argparse.ArgumentParser, *, timeout: float = 1.0) -> None:
    """--port / --tcp / --rtu-over-tcp, --baud, --parity, --timeout."""
    where = p.add_mutually_exclusive_group(required=True)
    where.add_argument("--port", metavar="PATH",
                       help="serial port, e.g. /dev/ttyUSB0 or /dev/serial/by-id/...")
    where.add_argument("--tcp", metavar="HOST:PORT", help="a Modbus TCP gateway")
    where.add_argument("--rtu-over-tcp", metavar="HOST:PORT",
                       help="RTU frames over TCP: a transparent serial server (\"raw\" mode)")
    p.add_argument("--baud", type=int, default=9600, help="baud rate (default 9600)")
    p.add_argument("--parity", default="N", choices=["N", "E", "O"], help="parity (default N)")
    p.add_argument("--timeout", type=float, default=timeout,
                   help=f"seconds to wait for a reply (default {timeout:g})")


def make_client(args: argparse.Namespace) -> Client:
    """The client the connection arguments describe (not yet open)."""
    if args.tcp:
        return client_for_address(args.tcp, timeout=args.timeout)
    if getattr(args, "rtu_over_tcp", None):
        return client_for_address(args.rtu_over_tcp, rtu_framing=True, timeout=args.timeout,
                                  what="--rtu-over-tcp")
    return RtuClient(args.port, args.baud, args.parity, timeout=args.timeout)


def _fmt(v: float, unit: str) -> str:
    if unit in ("V", "A"):
        return f"{v:.3f} {unit}"
    if unit == "°C":
        return f"{v:.3f} {unit}"
    return f"{v:g} {unit}".strip()


def render(data: CoolProTelemetry | CoolProIdentity | HubReading) -> str:
    """A readable table with units; no-value states shown by name."""
    if isinstance(data, HubReading):
        blocks = HUB.blocks
        head = ["ch"] + [f"{b.name.rsplit('_', 1)[0]} [{b.unit}]" for b in blocks]
        rows = [head]
        c = data.channels
        for ch in range(c):
            row = [str(ch + 1)]
            for b in blocks:
                st = State(data.raw_states[b.index * c + ch])
                v = data.values[b.index * c + ch]
                row.append(f"{v:g}" if st is State.VALUE else st.name.lower().replace("_", " "))
            rows.append(row)
        widths = [max(len(r[i]) for r in rows) for i in range(len(head))]
        lines = ["  ".join(cell.rjust(w) for cell, w in zip(r, widths, strict=True))
                 for r in rows]
        if data.unsupported:
            lines.append(f"not supported by this firmware: {', '.join(sorted(data.unsupported))}")
        return "\n".join(lines)
    if isinstance(data, CoolProTelemetry):
        lines = []
        for reg in COOLPRO.group("telemetry"):
            v = getattr(data, reg.name)
            if reg.name == "status":
                flags = [f.name for f in type(v) if f in v]
                text = f"0x{int(v):04X}" + (f" ({', '.join(flags)})" if flags else " (ok)")
                if v.reserved:
                    text += f" reserved bits 0x{v.reserved:04X}"
            elif reg.name == "uptime_s":
                text = f"{int(v)} s"
            else:
                text = _fmt(v, reg.unit)
            lines.append(f"{reg.description.split(' (')[0].split(',')[0]:<16} {text}")
        return "\n".join(lines)
    return "\n".join([
        f"{'Serial Number':<16} {data.serial_number}",
        f"{'Hardware':<16} rev {data.hardware_revision}",
        f"{'Firmware':<16} {data.firmware_version}",
        f"{'Manufactured':<16} {data.manufactured.isoformat()}",
    ])


def to_json(data: Any) -> dict[str, Any]:
    """A JSON-ready dict of a reading (None where there is no value)."""
    if isinstance(data, HubReading):
        return {"values": data.as_dict(),
                "states": {b.name: [State(s).name.lower() for s in data.states(b.name).tolist()]
                           for b in HUB.blocks},
                "unsupported": sorted(data.unsupported)}
    if isinstance(data, CoolProTelemetry):
        out: dict[str, Any] = {}
        for reg in COOLPRO.group("telemetry"):
            v = getattr(data, reg.name)
            out[reg.name] = int(v) if reg.name in ("status", "uptime_s") else (
                None if math.isnan(v) else v)
        out["status_flags"] = [f.name for f in type(data.status) if f in data.status]
        return out
    return {"serial_number": data.serial_number, "hardware_revision": data.hardware_revision,
            "firmware_version": data.firmware_version,
            "manufactured": data.manufactured.isoformat()}


def print_json(obj: Any) -> None:
    """Print one JSON document."""
    json.dump(obj, sys.stdout, indent=2, allow_nan=False)
    sys.stdout.write("\n")
