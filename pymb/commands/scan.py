"""``pymb scan``: which addresses answer on a bus, and which device each is."""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass

from pymb.client import Client
from pymb.commands._common import add_connection_args, make_client, print_json
from pymb.devices import HUB, CoolPro
from pymb.devices.maps import COOLPRO
from pymb.errors import (
    DeviceException,
    IllegalFunction,
    InvalidArgument,
    ModbusConnectionError,
    ModbusError,
    ModbusTimeout,
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Arguments of ``pymb scan``."""
    add_connection_args(p, timeout=0.05)
    p.add_argument("--range", default="1-255", metavar="A-B[,C...]",
                   help="addresses to try (default 1-255: the hub uses up to 255)")
    p.add_argument("--json", action="store_true", help="print JSON")


def parse_range(spec: str) -> list[int]:
    """``1-10,40,248-255`` -> the addresses, in order, without repeats."""
    out: list[int] = []
    try:
        for part in spec.split(","):
            lo, _, hi = part.strip().partition("-")
            a, b = int(lo), int(hi or lo)
            if not (1 <= a <= b <= 255):
                raise ValueError
            out.extend(x for x in range(a, b + 1) if x not in out)
    except ValueError:
        raise InvalidArgument(f"bad --range {spec!r}: use e.g. 1-247 or 1-10,40,250") from None
    return out


@dataclass
class Found:
    """One address that answered."""

    address: int
    device: str  #: coolpro, hub, or "unknown"
    detail: str


def probe(client: Client, address: int) -> Found | None:
    """What answers at ``address``, or None for silence."""
    try:
        ident = CoolPro(client, min(address, 247)).read_identity() if address <= 247 else None
        if ident is not None:
            return Found(address, "coolpro", f"serial {ident.serial_number}, firmware "
                         f"{ident.firmware_version}, hardware rev {ident.hardware_revision}")
    except ModbusTimeout:
        return None
    except IllegalFunction:
        pass  # the hub answers FC 0x04 with exception 01: try its own read
    except DeviceException as e:
        return Found(address, "unknown", f"answers FC 0x04 at {COOLPRO.span('identity')[1]} "
                     f"with exception {e.code:02X}")
    except ModbusConnectionError:
        raise
    except ModbusError as e:
        return Found(address, "unknown", f"garbled reply: {e.__class__.__name__}")
    try:
        client.read_holding_registers(HUB.first, 1, slave=address)
        return Found(address, "hub", "answers FC 0x03 at register 31 (channel 1 temperature)")
    except ModbusTimeout:
        return None
    except DeviceException as e:
        return Found(address, "unknown", f"answers with exception {e.code:02X}")
    except ModbusConnectionError:
        raise
    except ModbusError as e:
        return Found(address, "unknown", f"garbled reply: {e.__class__.__name__}")


def run(args: argparse.Namespace) -> int:
    """Try every address in the range; print what answered."""
    addresses = parse_range(args.range)
    found: list[Found] = []
    tty = sys.stderr.isatty()
    t0 = time.monotonic()
    with make_client(args) as client:
        for i, a in enumerate(addresses, 1):
            if tty:
                sys.stderr.write(f"\r\x1b[Kscanning {a} ({i}/{len(addresses)}), "
                                 f"{len(found)} found")
                sys.stderr.flush()
            f = probe(client, a)
            if f is not None:
                found.append(f)
                if tty:
                    sys.stderr.write(f"\r\x1b[K{f.address:3d}  {f.device:8s} {f.detail}\n")
    if tty:
        sys.stderr.write("\r\x1b[K")
    elapsed = time.monotonic() - t0
    if args.json:
        print_json({"port": client.port, "scanned": len(addresses), "seconds": elapsed,
                    "found": [f.__dict__ for f in found]})
    else:
        for f in found:
            print(f"{f.address:3d}  {f.device:8s} {f.detail}")
        print(f"{len(found)} device(s) in {len(addresses)} addresses, {elapsed:.1f} s",
              file=sys.stderr)
    return 0
